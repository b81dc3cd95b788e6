// GIVEN publisher configurations WHEN loaded THEN the shipped example is valid, every mistake is
// named with file:line:column and key path, and a password file others may read is refused.
#include "tools/mqtt/mqtt_config.hpp"

#include <gtest/gtest.h>
#include <sys/stat.h>

#include "tests/unit/mqtt/temp_dir.hpp"

namespace nccomp::tools::mqtt {
namespace {

using test::TempDir;

TEST(PublishConfig, TheShippedExampleLoadsWithItsDefaults) {
  nccomp::formats::Diagnostics diag;
  const auto c =
      load_publish_config(std::string(NCCOMP_SOURCE_DIR) + "/config/nccomp-publish.toml", diag);
  ASSERT_TRUE(c) << diag.to_string();
  EXPECT_EQ(c->site, "plant-1");
  EXPECT_EQ(c->machine, "mill-01");
  EXPECT_EQ(c->broker.client_id, "nccomp-publish-plant-1-mill-01");
  EXPECT_EQ(c->broker.max_inflight, 64);
  EXPECT_EQ(c->max_messages, 3'600'000);
  EXPECT_EQ(topic(c->site, c->machine, "alarms"), "nccomp/plant-1/mill-01/alarms");
}

TEST(PublishConfig, EveryMistakeNamesFileLineColumnAndKey) {
  TempDir d("nccomp_pubcfg");
  const std::string f = d.write("p.toml", R"([publish]
site = "plant 1"
machine = "m/1"
[broker]
uri = "tcp://b:1883"
ca_file = "ca.pem"
pasword_file = "x"
[queue]
max_messages = 3
[extra]
)");
  nccomp::formats::Diagnostics diag;
  EXPECT_FALSE(load_publish_config(f, diag));
  const auto& items = diag.items();
  ASSERT_EQ(items.size(), 6U) << diag.to_string();
  EXPECT_EQ(items[0].where.key_path, "extra");
  EXPECT_NE(items[0].message.find("unknown section"), std::string::npos);
  EXPECT_EQ(items[1].where.key_path, "publish.site");
  EXPECT_EQ(items[1].where.line, 2);
  EXPECT_EQ(items[1].where.file, f);
  EXPECT_EQ(items[2].where.key_path, "publish.machine");
  EXPECT_EQ(items[3].where.key_path, "broker.uri");
  EXPECT_NE(items[3].message.find("need a TLS address"), std::string::npos) << items[3].message;
  EXPECT_EQ(items[4].where.key_path, "broker.pasword_file");
  EXPECT_EQ(items[4].message, "unknown key");
  EXPECT_EQ(items[5].where.key_path, "queue.max_messages");
  EXPECT_EQ(nccomp::formats::format(items[5]).rfind(f + ":9:16: queue.max_messages: ", 0), 0U)
      << nccomp::formats::format(items[5]);

  nccomp::formats::Diagnostics none;
  EXPECT_FALSE(load_publish_config(d.write("q.toml", "[queue]\n"), none));
  ASSERT_EQ(none.items().size(), 2U);
  EXPECT_EQ(none.items()[0].where.key_path, "publish");
  EXPECT_EQ(none.items()[0].message, "required section is missing");
}

TEST(PublishConfig, BrokerChecks) {
  BrokerOptions b;
  b.uri = "http://x";
  EXPECT_NE(check_broker(b).find("not a broker address"), std::string::npos);
  b.uri = "ssl://";
  EXPECT_NE(check_broker(b).find("names no host"), std::string::npos);
  b.uri = "mqtts://b:8883";
  b.cert_file = "c.pem";
  EXPECT_NE(check_broker(b).find("go together"), std::string::npos);
  b.key_file = "k.pem";
  EXPECT_EQ(check_broker(b), "");
  b.password_file = "p";
  EXPECT_NE(check_broker(b).find("needs a username"), std::string::npos);
}

TEST(PublishConfig, APasswordFileOthersMayReadIsRefusedAndTheFirstLineIsThePassword) {
  TempDir d("nccomp_pw");
  const std::string f = d.write("pw", "s3cret\nignored\n");
  ::chmod(f.c_str(), 0644);
  try {
    (void)read_password_file(f);
    FAIL() << "a world-readable password file was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("mode 0644"), std::string::npos) << e.what();
    EXPECT_EQ(std::string(e.what()).find("s3cret"), std::string::npos) << e.what();
  }
  ::chmod(f.c_str(), 0640);
  EXPECT_EQ(read_password_file(f), "s3cret");
  ::chmod(d.write("empty", "\n").c_str(), 0600);
  EXPECT_THROW((void)read_password_file((d.path() / "empty").string()), std::runtime_error);
  EXPECT_THROW((void)read_password_file((d.path() / "none").string()), std::runtime_error);
}

}  // namespace
}  // namespace nccomp::tools::mqtt
