// A small, deterministic fuzz driver for targets written against libFuzzer's interface
// (`extern "C" int LLVMFuzzerTestOneInput(const uint8_t*, size_t)`), so the same targets run
// with g++ in CI (under ASan/UBSan) and with clang's -fsanitize=fuzzer for long runs.
//
// Usage: fuzz_x [CORPUS_DIR_OR_FILE ...] [-runs=N] [-seed=S] [-max_len=L]
// Every corpus file is run as is, then N inputs mutated from the corpus (byte flips, inserts,
// deletions, splices, interesting values) with a fixed seed, so a failure is reproducible.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace {

using Bytes = std::vector<std::uint8_t>;

void load(const std::filesystem::path& p, std::vector<Bytes>& corpus) {
  if (std::filesystem::is_directory(p)) {
    std::vector<std::filesystem::path> files;
    for (const auto& e : std::filesystem::directory_iterator(p)) {
      if (e.is_regular_file()) {
        files.push_back(e.path());
      }
    }
    std::sort(files.begin(), files.end());
    for (const auto& f : files) {
      load(f, corpus);
    }
    return;
  }
  std::ifstream in(p, std::ios::binary);
  corpus.emplace_back(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

Bytes mutate(const std::vector<Bytes>& corpus, std::mt19937_64& rng, std::size_t max_len) {
  static const char* const kTokens[] = {",", "\n", "\r\n", "nan", "-inf", "1e308", "-0", "\"",
                                        "=", "[", "]", "0x", "-", ".", "e", "#", " ", "\t"};
  Bytes b = corpus.empty() ? Bytes{} : corpus[rng() % corpus.size()];
  const int n = 1 + static_cast<int>(rng() % 8);
  for (int i = 0; i < n; ++i) {
    const std::size_t pos = b.empty() ? 0 : rng() % (b.size() + 1);
    switch (rng() % 7) {
      case 0:  // flip a bit
        if (!b.empty()) {
          b[pos % b.size()] ^= static_cast<std::uint8_t>(1U << (rng() % 8));
        }
        break;
      case 1:  // random byte
        if (!b.empty()) {
          b[pos % b.size()] = static_cast<std::uint8_t>(rng());
        }
        break;
      case 2:  // insert a random byte
        b.insert(b.begin() + static_cast<std::ptrdiff_t>(pos), static_cast<std::uint8_t>(rng()));
        break;
      case 3:  // delete a run
        if (!b.empty()) {
          const std::size_t start = pos % b.size();
          const std::size_t len = std::min<std::size_t>(1 + rng() % 16, b.size() - start);
          b.erase(b.begin() + static_cast<std::ptrdiff_t>(start),
                  b.begin() + static_cast<std::ptrdiff_t>(start + len));
        }
        break;
      case 4: {  // insert a token
        const char* t = kTokens[rng() % std::size(kTokens)];
        b.insert(b.begin() + static_cast<std::ptrdiff_t>(pos), t, t + std::strlen(t));
        break;
      }
      case 5:  // splice with another corpus entry
        if (!corpus.empty()) {
          const Bytes& o = corpus[rng() % corpus.size()];
          if (!o.empty()) {
            const std::size_t s = rng() % o.size();
            b.insert(b.begin() + static_cast<std::ptrdiff_t>(pos), o.begin() + static_cast<std::ptrdiff_t>(s), o.end());
          }
        }
        break;
      default:  // duplicate a run
        if (!b.empty()) {
          const std::size_t start = pos % b.size();
          const std::size_t len = std::min<std::size_t>(1 + rng() % 32, b.size() - start);
          Bytes run(b.begin() + static_cast<std::ptrdiff_t>(start),
                    b.begin() + static_cast<std::ptrdiff_t>(start + len));
          b.insert(b.begin() + static_cast<std::ptrdiff_t>(start), run.begin(), run.end());
        }
        break;
    }
  }
  if (b.size() > max_len) {
    b.resize(max_len);
  }
  return b;
}

}  // namespace

int main(int argc, char** argv) {
  long runs = 20000;
  unsigned long long seed = 1;
  std::size_t max_len = 4096;
  std::vector<Bytes> corpus;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a.rfind("-runs=", 0) == 0) {
      runs = std::strtol(a.c_str() + 6, nullptr, 10);
    } else if (a.rfind("-seed=", 0) == 0) {
      seed = std::strtoull(a.c_str() + 6, nullptr, 10);
    } else if (a.rfind("-max_len=", 0) == 0) {
      max_len = std::strtoul(a.c_str() + 9, nullptr, 10);
    } else {
      load(a, corpus);
    }
  }
  for (const auto& c : corpus) {
    LLVMFuzzerTestOneInput(c.data(), c.size());
  }
  std::mt19937_64 rng(seed);
  for (long i = 0; i < runs; ++i) {
    const Bytes b = mutate(corpus, rng, max_len);
    LLVMFuzzerTestOneInput(b.data(), b.size());
  }
  std::printf("fuzz: %zu corpus inputs and %ld mutated inputs ran without a finding (seed %llu)\n",
              corpus.size(), runs, seed);
  return 0;
}
