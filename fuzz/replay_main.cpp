// A stand-in for libFuzzer's driver, for builds without clang: runs a fuzz target's
// LLVMFuzzerTestOneInput once on every file named on the command line or found in a directory
// named there (not recursively; sorted, so runs are repeatable), and prints how many ran.
// ctest replays the saved corpus with it (ctest -L fuzz). A crash or an abort of the target
// fails the run; so does finding no input at all (a misspelt corpus path).
//
//   fuzz_codec_replay fuzz/corpus/codec [more dirs or files]
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

namespace fs = std::filesystem;

int main(int argc, char** argv) {
  std::vector<fs::path> files;
  for (int i = 1; i < argc; ++i) {
    const fs::path p(argv[i]);
    std::error_code ec;
    if (fs::is_directory(p, ec)) {
      std::vector<fs::path> in;
      for (const auto& e : fs::directory_iterator(p, ec))
        if (e.is_regular_file()) in.push_back(e.path());
      std::sort(in.begin(), in.end());
      files.insert(files.end(), in.begin(), in.end());
    } else if (fs::is_regular_file(p, ec)) {
      files.push_back(p);
    } else {
      std::fprintf(stderr, "%s: no such file or directory\n", argv[i]);
      return 2;
    }
  }
  if (files.empty()) {
    std::fprintf(stderr, "usage: %s CORPUS_DIR_OR_FILE...: no input found\n", argv[0]);
    return 2;
  }
  const auto start = std::chrono::steady_clock::now();
  size_t bytes = 0;
  for (const fs::path& f : files) {
    std::ifstream in(f, std::ios::binary);
    std::vector<char> content((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (!in.eof() && in.fail()) {
      std::fprintf(stderr, "%s: cannot read\n", f.c_str());
      return 2;
    }
    // An exact-size heap copy, as libFuzzer passes it (a sanitizer build sees overreads).
    std::unique_ptr<uint8_t[]> data(new uint8_t[content.size() ? content.size() : 1]);
    std::copy(content.begin(), content.end(), data.get());
    bytes += content.size();
    std::fflush(stdout);
    LLVMFuzzerTestOneInput(data.get(), content.size());
  }
  const double s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("replayed %zu inputs (%zu bytes) in %.2f s\n", files.size(), bytes, s);
  return 0;
}
