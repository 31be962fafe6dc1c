// The engine in process, from an installed package: a unit cube given as a hull of its
// corners and centre (the engine builds the hull), dropped from 10 m for one second.
// Prints its mass and height; tests/package/test_package.sh checks them.
#include <cstdio>
#include <vector>

#include "phys/world/world.h"

int main() {
  phys::World world;
  std::vector<phys::Vec3> points;
  for (float x : {-0.5f, 0.5f})
    for (float y : {-0.5f, 0.5f})
      for (float z : {-0.5f, 0.5f}) points.push_back({x, y, z});
  points.push_back({0, 0, 0});
  phys::BodyDef cube;
  cube.position = {0, 0, 10};
  cube.shapes.push_back({phys::ShapeGeom::hullOf(points), {}, {}});
  phys::BodyId id;
  const phys::Status st = world.createBody(cube, &id);
  if (!st.ok()) {
    std::printf("createBody: %s\n", st.message.c_str());
    return 1;
  }
  for (int i = 0; i < 60; ++i) world.step();
  phys::BodyState s;
  world.getBody(id, &s);
  std::printf("mass=%.3f z=%.4f t=%.4f\n", s.mass, s.position.z, world.time());
  return 0;
}
