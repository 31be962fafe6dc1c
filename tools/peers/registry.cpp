// Which peers this build has: each adapter's .cmake defines PHYS_PEER_<ENGINE> when its
// package was found (Box3D's: when PHYS_BOX3D_DIR names its source tree).
#include "peers/peer.h"

namespace phys::peers {

std::vector<std::string> peerNames() {
  std::vector<std::string> names;
#ifdef PHYS_PEER_BULLET
  names.push_back("bullet");
#endif
#ifdef PHYS_PEER_ODE
  names.push_back("ode");
#endif
#ifdef PHYS_PEER_MUJOCO
  names.push_back("mujoco");
#endif
#ifdef PHYS_PEER_BOX3D
  names.push_back("box3d");
#endif
  return names;
}

std::unique_ptr<PeerEngine> makePeer(const std::string& name) {
#ifdef PHYS_PEER_BULLET
  if (name == "bullet") return makeBulletPeer();
#endif
#ifdef PHYS_PEER_ODE
  if (name == "ode") return makeOdePeer();
#endif
#ifdef PHYS_PEER_MUJOCO
  if (name == "mujoco") return makeMujocoPeer();
#endif
#ifdef PHYS_PEER_BOX3D
  if (name == "box3d") return makeBox3dPeer();
#endif
  (void)name;
  return nullptr;
}

}  // namespace phys::peers
