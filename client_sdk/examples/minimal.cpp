// A minimal physd client: connect, create a world, spawn a ground and a few boxes, run it at
// 60 Hz and print a few state frames.
//
//   build/server/physd --config configs/physd.toml &
//   build/client_sdk/physclient_minimal [domain]
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "phys/client/client.h"

int main(int argc, char** argv) {
  namespace pc = phys::client;
  pc::ClientOptions options;
  options.domain = argc > 1 ? uint32_t(std::atoi(argv[1])) : 0;
  options.name = "minimal";
  try {
    pc::Client client(options);
    pc::ServerInfo server = client.connect();
    std::printf("connected to %s %s\n", server.name.c_str(), server.version.c_str());

    const std::string name = "minimal-" + std::to_string(client.clientId() % 100000);
    pc::WorldHandle world = client.createWorld({name, "", std::nullopt, 0}).get();

    std::vector<phys::BodyDef> bodies;
    phys::BodyDef ground;
    ground.type = phys::BodyType::Static;
    phys::ShapeDef plane;
    plane.geom = phys::ShapeGeom::plane({0, 0, 1}, 0);
    ground.shapes.push_back(plane);
    bodies.push_back(ground);
    for (int i = 0; i < 5; ++i) {
      phys::BodyDef box;
      box.position = {0, 0, 0.5f + 1.1f * float(i)};
      phys::ShapeDef s;
      s.geom = phys::ShapeGeom::box({0.5f, 0.5f, 0.5f});
      box.shapes.push_back(s);
      bodies.push_back(box);
    }
    std::vector<uint64_t> ids = world.spawn(bodies).get();
    std::printf("world %u: spawned %zu bodies\n", world.id(), ids.size());

    pc::Subscription sub = world.subscribe();
    world.run(60).get();
    uint64_t tick = 0;
    for (int n = 0; n < 5; ++n) {
      auto frame = sub.waitForFrame(tick, std::chrono::seconds(5));
      if (!frame) break;
      tick = frame->tick + 20;  // about three frames a second
      const pc::BodyState& top = frame->bodies.back();
      std::printf("tick %llu  t=%.2f s  %zu bodies  top box z=%.3f\n",
                  (unsigned long long)frame->tick, frame->time, frame->bodies.size(),
                  double(top.position.z));
    }
    world.destroy().get();
  } catch (const pc::Error& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
  return 0;
}
