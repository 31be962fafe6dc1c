// The engine's rooms point one way (docs/ARCHITECTURE.md, "Map"): no file of
// physics/dynamics/ includes a world header, private ("world/world_impl.h") or public
// ("phys/world/world.h"). What the dynamics needs of the world's records lives in
// dynamics/records.h or comes to it as an argument.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

namespace phys {
namespace {

TEST(Layers, DynamicsIncludesNoWorldHeader) {
  namespace fs = std::filesystem;
  const fs::path root = fs::path(PHYS_SOURCE_DIR) / "physics" / "dynamics";
  ASSERT_TRUE(fs::is_directory(root)) << root;
  int files = 0;
  std::string found;
  for (const fs::directory_entry& e : fs::recursive_directory_iterator(root)) {
    if (!e.is_regular_file()) continue;
    ++files;
    std::ifstream in(e.path());
    ASSERT_TRUE(in) << e.path();
    std::string line;
    for (int n = 1; std::getline(in, line); ++n) {
      // An include line: '#', then "include", spaces allowed around the '#'.
      const size_t hash = line.find_first_not_of(" \t");
      if (hash == std::string::npos || line[hash] != '#') continue;
      const size_t word = line.find_first_not_of(" \t", hash + 1);
      if (word == std::string::npos || line.compare(word, 7, "include") != 0) continue;
      if (line.find("world/") != std::string::npos)
        found +=
            fs::relative(e.path(), root).string() + ":" + std::to_string(n) + ": " + line + "\n";
    }
  }
  // The walk found the room (a moved tree would pass with nothing read).
  EXPECT_GT(files, 10);
  EXPECT_TRUE(found.empty()) << "physics/dynamics/ includes world/:\n" << found;
}

}  // namespace
}  // namespace phys
