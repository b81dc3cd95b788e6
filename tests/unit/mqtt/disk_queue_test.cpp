// GIVEN the publisher's queue on disk WHEN messages are queued, sent, acknowledged, the queue
// overflows or the process dies THEN messages leave in order, an overflow drops the oldest and
// counts them per kind, and after a crash no sequence number is given twice and nothing that was
// flushed is lost.
#include "tools/mqtt/disk_queue.hpp"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>

#include "tests/unit/mqtt/temp_dir.hpp"

namespace nccomp::tools::mqtt {
namespace {

using test::TempDir;
namespace fs = std::filesystem;

std::vector<std::uint64_t> drain(DiskQueue& q, std::vector<std::uint64_t>* ids = nullptr) {
  std::vector<std::uint64_t> seqs;
  QueuedMessage m;
  while (q.next(m)) {
    seqs.push_back(m.seq);
    if (ids != nullptr) ids->push_back(m.id);
    EXPECT_EQ(m.payload, "{\"n\":" + std::to_string(m.seq) + "}");
  }
  return seqs;
}

void put(DiskQueue& q, const std::string& kind, int n, const std::string& cursor = "c") {
  for (int i = 0; i < n; ++i) {
    const std::uint64_t seq = q.next_seq(kind);
    q.append(kind, seq, cursor, "{\"n\":" + std::to_string(seq) + "}");
  }
}

TEST(DiskQueue, MessagesLeaveInOrderAndARewindSendsTheUnacknowledgedAgain) {
  TempDir d("nccomp_q");
  DiskQueue q({d.str() + "/q", 1000, 0.0});
  q.open();
  put(q, "measurements", 3);
  put(q, "alarms", 1);
  put(q, "measurements", 2);
  QueuedMessage m;
  EXPECT_FALSE(q.next(m));  // nothing is sent before it is on disk
  q.flush();
  std::vector<std::uint64_t> ids;
  EXPECT_EQ(drain(q, &ids), (std::vector<std::uint64_t>{1, 2, 3, 1, 4, 5}));
  ASSERT_EQ(ids, (std::vector<std::uint64_t>{1, 2, 3, 4, 5, 6}));
  q.ack(1);
  q.ack(3);  // out of order: 2 is still open
  EXPECT_EQ(q.queued(), 5U);
  q.rewind();
  ids.clear();
  drain(q, &ids);
  EXPECT_EQ(ids, (std::vector<std::uint64_t>{2, 4, 5, 6}));
  for (std::uint64_t id : {2U, 4U, 5U, 6U}) q.ack(id);
  EXPECT_EQ(q.queued(), 0U);
  EXPECT_EQ(q.acknowledged(), 6U);
}

TEST(DiskQueue, AFullQueueDropsTheOldestAndCountsThemPerKind) {
  TempDir d("nccomp_q_full");
  // 32 messages at most: segments of 2 messages.
  DiskQueue q({d.str(), 32, 0.0});
  q.open();
  put(q, "alarms", 2);
  put(q, "measurements", 38);
  q.flush();
  // 40 queued > 32: the oldest 8 go (whole segments), the 2 alarms among them.
  EXPECT_EQ(q.queued(), 32U);
  EXPECT_EQ(q.dropped("alarms"), 2U);
  EXPECT_EQ(q.dropped("measurements"), 6U);
  const auto seqs = drain(q);
  ASSERT_EQ(seqs.size(), 32U);
  EXPECT_EQ(seqs.front(), 7U);
  EXPECT_EQ(seqs.back(), 38U);
  // The counts and the queue survive a restart.
  q.close();
  DiskQueue again({d.str(), 32, 0.0});
  again.open();
  EXPECT_EQ(again.dropped("measurements"), 6U);
  EXPECT_EQ(again.queued(), 32U);
  EXPECT_EQ(drain(again).front(), 7U);
  EXPECT_EQ(again.next_seq("measurements"), 39U);
}

TEST(DiskQueue, AcknowledgedSegmentsAreDeleted) {
  TempDir d("nccomp_q_del");
  DiskQueue q({d.str(), 32, 0.0});
  q.open();
  put(q, "measurements", 10);
  q.flush();
  EXPECT_EQ(q.segments(), 5U);
  std::vector<std::uint64_t> ids;
  drain(q, &ids);
  for (std::uint64_t id : ids) q.ack(id);
  q.flush();
  EXPECT_EQ(q.segments(), 1U);  // the newest stays: it is appended to
  std::size_t files = 0;
  for (const auto& e : fs::directory_iterator(d.path())) files += e.path().extension() == ".q";
  EXPECT_EQ(files, 1U);
}

TEST(DiskQueue, TheReaderGoesOnWhenTheSegmentItFinishedIsDeleted) {
  // Found by the broker tests: every message of a segment sent and acknowledged, the next
  // message starts a new segment, the old one is deleted: the reader must go on there.
  TempDir d("nccomp_q_reader");
  DiskQueue q({d.str(), 32, 0.0});  // segments of 2
  q.open();
  put(q, "measurements", 2);
  q.flush();
  std::vector<std::uint64_t> ids;
  EXPECT_EQ(drain(q, &ids), (std::vector<std::uint64_t>{1, 2}));
  for (std::uint64_t id : ids) q.ack(id);
  q.flush();
  put(q, "measurements", 3);
  q.flush();
  EXPECT_EQ(q.segments(), 2U);
  EXPECT_EQ(drain(q), (std::vector<std::uint64_t>{3, 4, 5}));
}

TEST(DiskQueue, AfterACrashSequencesGoOnAndFlushedMessagesAreThere) {
  TempDir d("nccomp_q_crash");
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    DiskQueue q({d.str(), 1000, 0.0});
    q.open();
    put(q, "measurements", 5, "cursor-5");
    q.flush();                              // on disk, the state not yet saved (1 s)
    put(q, "measurements", 1, "cursor-6");  // buffered only: lost in the crash
    ::_exit(0);                             // no close(), no destructor
  }
  int status = 0;
  ::waitpid(pid, &status, 0);
  ASSERT_TRUE(WIFEXITED(status));
  // A torn last line, as a crash in the middle of a write leaves it.
  for (const auto& e : fs::directory_iterator(d.path())) {
    if (e.path().extension() == ".q") {
      std::ofstream(e.path(), std::ios::app) << "6\tmeasurements\t6\tcursor-6\t{\"n\"";
    }
  }
  DiskQueue q({d.str(), 1000, 0.0});
  q.open();
  EXPECT_EQ(q.next_seq("measurements"), 6U);  // rolled forward from the lines
  EXPECT_EQ(q.cursor(), "cursor-5");
  EXPECT_EQ(drain(q), (std::vector<std::uint64_t>{1, 2, 3, 4, 5}));
  put(q, "measurements", 1, "cursor-6");
  q.flush();
  EXPECT_EQ(drain(q), (std::vector<std::uint64_t>{6}));
}

TEST(DiskQueue, AStateFileItCannotTrustIsRefusedNotGuessed) {
  TempDir d("nccomp_q_bad");
  d.write("state.json", "{\"head\": 1}");
  DiskQueue q({d.str(), 1000, 0.0});
  try {
    q.open();
    FAIL() << "a state without its sequence numbers was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("state.json' is not valid"), std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace nccomp::tools::mqtt
