// Warm starting depends on contact points keeping their feature ids while they persist.
#include <gtest/gtest.h>

#include <map>
#include <set>

#include "phys/scene/scene.h"
#include "phys/world/world.h"

using namespace phys;

TEST(WarmStart, PyramidContactPointsKeepTheirFeatureIds) {
  // Upper boxes straddle two lower ones with their corners exactly on the lower boxes' side
  // planes: the case where sub-millimetre drift used to flip points between "incident
  // vertex" and "clip point" ids and throw their warm start away.
  Scene scene;
  Status st = parseScene(R"({
    "name": "pyramid_8",
    "bodies": [{"name": "ground", "type": "static", "shapes": [{"type": "plane"}]}],
    "generators": [{"type": "pyramid", "name": "p", "base": 8, "half_extent": 0.5}]
  })",
                         "inline", &scene);
  ASSERT_TRUE(st.ok()) << st.message;
  World world(scene.world);
  std::vector<BodyId> ids;
  ASSERT_TRUE(instantiateScene(scene, &world, &ids).ok());
  using Key = std::pair<uint64_t, uint64_t>;
  std::map<Key, std::set<uint32_t>> prev;
  int total = 0, matched = 0;
  for (int i = 0; i < 180; ++i) {
    world.step();
    std::map<Key, std::set<uint32_t>> cur;
    for (const ContactInfo& c : world.contacts()) {
      Key k{c.shapeA.packed(), c.shapeB.packed()};
      for (int p = 0; p < c.manifold.count; ++p) {
        uint32_t id = c.manifold.points[p].featureId;
        cur[k].insert(id);
        if (i < 60) continue;  // let it settle first
        ++total;
        auto it = prev.find(k);
        if (it != prev.end() && it->second.count(id)) ++matched;
      }
    }
    prev = std::move(cur);
  }
  ASSERT_GT(total, 0);
  EXPECT_EQ(matched, total) << "points that lost their id (and warm start): " << total - matched;
}
