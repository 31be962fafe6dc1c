// Islands and sleeping: the awake body list every per-body stage walks, the islands that fall
// asleep once all their bodies have rested long enough, and everything that wakes them.
//
// Islands are found again after every accepted step, by union-find over the awake dynamic
// bodies joined by contacts with points and by joints (as Jolt does), so no island ever has to
// be split when a contact ends. Only sleeping islands are kept: a sleeping island holds its
// bodies and their touching contacts (with the impulses that warm-start them when it wakes).
// A sleeping body's proxies are static in the broad phase, so it makes no pairs with static or
// other sleeping bodies: a world whose bodies all sleep finds no pairs, collides nothing and
// solves nothing, whatever its size. See docs/ARCHITECTURE.md "Islands and sleeping".
#include <algorithm>
#include <cmath>

#include "phys/world/world.h"
#include "world/world_impl.h"

namespace phys {

namespace {

bool contactBefore(const Contact& x, const Contact& y) {
  return x.shapeA != y.shapeA ? x.shapeA < y.shapeA : x.shapeB < y.shapeB;
}

/// Merges sorted `add` into sorted `into`; a contact already in `into` (the same shape pair)
/// keeps its entry there.
void mergeContacts(std::vector<Contact>* into, const std::vector<Contact>& add,
                   std::vector<Contact>* scratch) {
  if (add.empty()) return;
  scratch->clear();
  scratch->reserve(into->size() + add.size());
  size_t i = 0, j = 0;
  while (i < into->size() || j < add.size()) {
    if (j == add.size() || (i < into->size() && !contactBefore(add[j], (*into)[i]))) {
      const bool same = j < add.size() && !contactBefore((*into)[i], add[j]);
      scratch->push_back((*into)[i++]);
      if (same) ++j;
    } else {
      scratch->push_back(add[j++]);
    }
  }
  into->swap(*scratch);
}

bool moving(const BodyRec& b) {
  return !(b.v == Vec3{}) || !(b.w == Vec3{});
}

}  // namespace

bool World::Impl::wakesSleeper(const BodyRec& other) {
  return other.type == BodyType::Dynamic || (other.type == BodyType::Kinematic && moving(other));
}

Status World::validate(const SleepSettings& s) {
  if (!(std::isfinite(s.time) && s.time > 0 && s.time <= 1e6f))
    return Status::Error(StatusCode::InvalidArgument, "sleep time must be in (0, 1e6] s");
  if (!(std::isfinite(s.linearSpeed) && s.linearSpeed >= 0) ||
      !(std::isfinite(s.angularSpeed) && s.angularSpeed >= 0))
    return Status::Error(StatusCode::InvalidArgument,
                         "sleep speeds must be finite and >= 0 (m/s, rad/s)");
  return Status::Ok();
}

Status World::setSleepSettings(const SleepSettings& s) {
  Status st = validate(s);
  if (!st.ok()) return st;
  const SleepSettings& old = impl_->def.sleep;
  if (!s.enabled || s.time != old.time || s.linearSpeed != old.linearSpeed ||
      s.angularSpeed != old.angularSpeed)
    impl_->wakeEverything();
  impl_->def.sleep = s;
  return st;
}

Status World::setAllowSleep(BodyId id, bool allow) {
  BodyRec* b = impl_->bodies.get(id);
  if (!b) return Status::Error(StatusCode::NotFound, "body id is unknown or stale");
  b->allowSleep = allow;
  if (!allow) impl_->wake(id.index);
  return Status::Ok();
}

Status World::wakeBody(BodyId id) {
  if (!impl_->bodies.get(id))
    return Status::Error(StatusCode::NotFound, "body id is unknown or stale");
  impl_->wake(id.index);
  return Status::Ok();
}

int World::awakeBodyCount() const {
  return int(impl_->awakeBodies.size());
}

void World::awakeBodies(std::vector<BodyId>* out) const {
  out->clear();
  out->reserve(impl_->awakeBodies.size());
  for (uint32_t slot : impl_->awakeBodies) out->push_back(impl_->bodies.idAt(slot));
}

bool World::isSleeping(BodyId id) const {
  const BodyRec* b = impl_->bodies.get(id);
  return b && b->asleep();
}

// ---------------------------------------------------------------------------------------------
// The awake list

void World::Impl::awakeInsert(uint32_t slot) {
  auto it = std::lower_bound(awakeBodies.begin(), awakeBodies.end(), slot);
  if (it == awakeBodies.end() || *it != slot) awakeBodies.insert(it, slot);
}

void World::Impl::awakeErase(uint32_t slot) {
  auto it = std::lower_bound(awakeBodies.begin(), awakeBodies.end(), slot);
  if (it != awakeBodies.end() && *it == slot) awakeBodies.erase(it);
}

void World::Impl::rebuildAwake() {
  awakeBodies.clear();
  sleepingBodyCount = 0;
  for (uint32_t i = 0; i < bodies.capacity(); ++i) {
    if (!bodies.alive(i)) continue;
    const BodyRec& b = bodies.at(i);
    if (b.awake()) awakeBodies.push_back(i);
    if (b.asleep()) ++sleepingBodyCount;
  }
  stats.sleepingBodies = sleepingBodyCount;
  sleepingPotentialValid = false;
  stats.sleepingIslands = 0;
  for (const SleepingIsland& is : islands) stats.sleepingIslands += !is.bodies.empty();
}

double World::Impl::sleepingPotential() const {
  if (!sleepingPotentialValid) {
    double e = 0;
    for (const SleepingIsland& is : islands) e += is.potential;
    sleepingPotentialSum = e;
    sleepingPotentialValid = true;
  }
  return sleepingPotentialSum;
}

// ---------------------------------------------------------------------------------------------
// Waking

void World::Impl::wakeIsland(int32_t k) {
  SleepingIsland& is = islands[size_t(k)];
  // The stored impulses are per substep of the step they were solved in: scaled to the
  // current unit, as rescaleWarmStarts does for the awake contacts.
  const float scale = impulseScale(is.substepTime, stats.substepTime);
  if (scale != 1) {
    scaleImpulses(&is.contacts, scale);
    // Its joints too, once each (a joint between two of its bodies is listed by both).
    for (uint32_t slot : is.bodies)
      for (JointId jid : bodies.at(slot).joints) {
        JointRec& j = *joints.get(jid);
        const BodyRec* a = j.def.bodyA.isNull() ? nullptr : bodies.get(j.def.bodyA);
        const bool listedByA = a && a->island == k;
        if (listedByA && !(j.def.bodyA == bodies.idAt(slot))) continue;  // A scales it
        for (float& f : j.impulses) f *= scale;
      }
  }
  const double g = length(def.gravity);
  for (uint32_t slot : is.bodies) {
    BodyRec& b = bodies.at(slot);
    b.island = -1;
    b.sleepTime = 0;
    for (ShapeId sid : b.shapes) broadPhase.setStatic(shapes.get(sid)->proxy, false);
    deviceEdited(slot);  // goes up to the device as dynamic again
    if (!b.joints.empty()) deviceJointsChanged();
    if (snapshotValid) {
      // Woken inside a step: a rollback puts the body back here, awake (a wake is not undone).
      snapshot.bodies.push_back({slot, b.xf, b.com, b.v, b.w, b.force, b.torque});
      snapshot.liftEnergy += 0.1 * g * b.mass;
      for (JointId jid : b.joints) {
        const JointRec& j = *joints.get(jid);
        Snapshot::JointImpulses ji{jid.index, j.impulseCount, {}};
        std::copy(j.impulses, j.impulses + JointRec::kMaxRows, ji.impulses);
        snapshot.jointImpulses.push_back(ji);
      }
    }
  }
  std::vector<uint32_t> merged;
  merged.reserve(awakeBodies.size() + is.bodies.size());
  std::merge(awakeBodies.begin(), awakeBodies.end(), is.bodies.begin(), is.bodies.end(),
             std::back_inserter(merged));
  awakeBodies.swap(merged);
  sleepingBodyCount -= int(is.bodies.size());
  if (snapshotValid) mergeContacts(&snapshot.contacts, is.contacts, &contactScratch);
  mergeContacts(&contacts, is.contacts, &contactScratch);
  std::vector<uint32_t>().swap(is.bodies);
  std::vector<Contact>().swap(is.contacts);
  is.potential = 0;
  freeIslands.push_back(uint32_t(k));
  sleepingPotentialValid = false;
  stats.sleepingIslands--;
  stats.sleepingBodies = sleepingBodyCount;
}

void World::Impl::wakeAll() {
  for (size_t k = 0; k < islands.size(); ++k)
    if (!islands[k].bodies.empty()) wakeIsland(int32_t(k));
}

void World::Impl::wakeEverything() {
  wakeAll();
  for (uint32_t slot : awakeBodies) bodies.at(slot).sleepTime = 0;
}

void World::Impl::wake(uint32_t slot) {
  BodyRec& b = bodies.at(slot);
  if (b.asleep()) wakeIsland(b.island);
  b.sleepTime = 0;
}

void World::Impl::wakeNeighbours(uint32_t slot) {
  if (sleepingBodyCount == 0) return;
  std::vector<int32_t> found;
  const BodyRec& b = bodies.at(slot);
  for (ShapeId sid : b.shapes) {
    const ShapeRec& s = *shapes.get(sid);
    if (s.proxy < 0) continue;
    broadPhase.query(broadPhase.fatAABB(s.proxy), [&](uint32_t user) {
      const BodyRec& o = *bodies.get(shapes.at(user).body);
      if (o.asleep()) found.push_back(o.island);
    });
  }
  for (JointId jid : b.joints) {
    const JointDef& d = joints.get(jid)->def;
    for (BodyId other : {d.bodyA, d.bodyB})
      if (const BodyRec* o = bodies.get(other); o && o->asleep()) found.push_back(o->island);
  }
  std::sort(found.begin(), found.end());
  found.erase(std::unique(found.begin(), found.end()), found.end());
  for (int32_t k : found) wakeIsland(k);
}

void World::Impl::wakeTouched() {
  if (sleepingBodyCount == 0) return;
  wakeList.clear();
  for (const Contact& c : contacts) {
    if (c.manifold.count == 0) continue;
    const BodyRec& A = bodies.at(c.bodyA.index);
    const BodyRec& B = bodies.at(c.bodyB.index);
    if (A.asleep() == B.asleep()) continue;
    const BodyRec& sleeper = A.asleep() ? A : B;
    if (wakesSleeper(A.asleep() ? B : A)) wakeList.push_back(uint32_t(sleeper.island));
  }
  std::sort(wakeList.begin(), wakeList.end());
  wakeList.erase(std::unique(wakeList.begin(), wakeList.end()), wakeList.end());
  for (uint32_t k : wakeList) wakeIsland(int32_t(k));
  wakeJointedToMovingKinematic();
}

void World::Impl::wakeJointedToMovingKinematic() {
  if (sleepingBodyCount == 0) return;
  wakeList.clear();
  // Joints from moving kinematic bodies (a dynamic body's joints share its island).
  for (uint32_t slot : awakeBodies) {
    const BodyRec& b = bodies.at(slot);
    if (b.type != BodyType::Kinematic || b.joints.empty() || !moving(b)) continue;
    for (JointId jid : b.joints) {
      const JointDef& d = joints.get(jid)->def;
      for (BodyId other : {d.bodyA, d.bodyB})
        if (const BodyRec* o = bodies.get(other); o && o->asleep())
          wakeList.push_back(uint32_t(o->island));
    }
  }
  std::sort(wakeList.begin(), wakeList.end());
  wakeList.erase(std::unique(wakeList.begin(), wakeList.end()), wakeList.end());
  for (uint32_t k : wakeList) wakeIsland(int32_t(k));
}

void World::Impl::collectStepJoints() {
  stepJoints.clear();
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    if (sleepingBodyCount > 0) {
      // The bodies of a joint between two dynamic bodies sleep together; one to a static or
      // kinematic body sleeps with its dynamic body.
      const JointDef& d = joints.at(i).def;
      const BodyRec* A = d.bodyA.isNull() ? nullptr : bodies.get(d.bodyA);
      if (bodies.get(d.bodyB)->asleep() || (A && A->asleep())) continue;
    }
    stepJoints.push_back(i);
  }
}

// ---------------------------------------------------------------------------------------------
// Falling asleep

void World::Impl::updateSleep(float dt) {
  stats.awakeIslands = 0;
  stats.sleepingBodies = sleepingBodyCount;
  if (!sleepActive()) return;
  const SleepSettings& z = def.sleep;

  // Rest timers, each body its own, on the world's threads. Kinematic bodies never sleep
  // (they are driven; a resting one holds what sleeps on it without waking it).
  forEachRange(awakeBodies.size(), [&](size_t begin, size_t end) {
    for (size_t k = begin; k < end; ++k) {
      BodyRec& b = bodies.at(awakeBodies[k]);
      if (b.type != BodyType::Dynamic) continue;
      float reach = 0;
      for (ShapeId sid : b.shapes) reach = std::max(reach, shapes.get(sid)->boundRadius);
      const float angular =
          reach > 0 ? std::min(z.angularSpeed, z.linearSpeed / reach) : z.angularSpeed;
      const bool slow = b.allowSleep && lengthSquared(b.v) <= z.linearSpeed * z.linearSpeed &&
                        lengthSquared(b.w) <= angular * angular;
      b.sleepTime = slow ? b.sleepTime + dt : 0;
    }
  });

  // Islands: union-find over the awake bodies (by their solver index, 1 + their place in
  // awakeBodies, as this step's buildSolverBodies or stepOnDevice numbered them), joined by
  // contacts with points and by joints between dynamic bodies. The root is the lowest index
  // (deterministic).
  const size_t n = awakeBodies.size();
  islandSets.reset(n);
  auto root = [&](int32_t i) { return islandSets.root(i); };
  auto join = [&](const BodyRec& A, const BodyRec& B) {
    if (A.type != BodyType::Dynamic || B.type != BodyType::Dynamic || !A.awake() || !B.awake())
      return;
    islandSets.join(A.solverIndex - 1, B.solverIndex - 1);
  };
  auto touch = [&](BodyRec& A, BodyRec& B) {
    // Carried by a moving kinematic body: not at rest, whatever its speed.
    if (A.type == BodyType::Kinematic && moving(A)) B.sleepTime = 0;
    if (B.type == BodyType::Kinematic && moving(B)) A.sleepTime = 0;
    join(A, B);
  };
  if (lastStepOnCpu) {
    for (const Contact& c : contacts)
      if (c.manifold.count > 0) touch(bodies.at(c.bodyA.index), bodies.at(c.bodyB.index));
  } else {
    for (auto [a, b] : deviceTouches) touch(bodies.at(a), bodies.at(b));
  }
  if (!lastStepOnCpu) collectStepJoints();  // the CPU step collected them
  for (uint32_t ji : stepJoints) {
    const JointDef& d = joints.at(ji).def;
    if (d.bodyA.isNull()) continue;
    BodyRec& A = bodies.at(d.bodyA.index);
    BodyRec& B = bodies.at(d.bodyB.index);
    if (A.type == BodyType::Kinematic && moving(A)) B.sleepTime = 0;
    if (B.type == BodyType::Kinematic && moving(B)) A.sleepTime = 0;
    join(A, B);
  }
  // An island sleeps when its least rested body has rested long enough.
  std::vector<float> rested(n, 0.0f);
  std::vector<uint8_t> dynamic(n, 0);
  for (size_t i = 0; i < n; ++i) {
    const BodyRec& b = bodies.at(awakeBodies[i]);
    if (b.type != BodyType::Dynamic) continue;
    dynamic[i] = 1;
    const size_t r = size_t(root(int32_t(i)));
    rested[r] = r == i ? b.sleepTime : std::min(rested[r], b.sleepTime);
  }
  // Roots come before their members (the lowest index is the root), so rested[r] is final
  // for every island once the loop above is over.
  std::vector<int32_t> newIsland(n, -1);  // by root: the island it becomes
  std::vector<int32_t> sleepers;          // new island indices, in order
  int awakeIslands = 0;
  for (size_t i = 0; i < n; ++i) {
    if (!dynamic[i] || size_t(root(int32_t(i))) != i) continue;
    if (!(rested[i] >= z.time)) {
      ++awakeIslands;
      continue;
    }
    int32_t k;
    if (!freeIslands.empty()) {
      k = int32_t(freeIslands.back());
      freeIslands.pop_back();
    } else {
      k = int32_t(islands.size());
      islands.emplace_back();
    }
    newIsland[i] = k;
    sleepers.push_back(k);
  }
  stats.awakeIslands = awakeIslands;
  if (sleepers.empty()) return;

  // The sleepers: at rest, out of the step, their proxies static.
  const Vec3 g = def.gravity;
  for (size_t i = 0; i < n; ++i) {
    if (!dynamic[i]) continue;
    const int32_t k = newIsland[size_t(root(int32_t(i)))];
    if (k < 0) continue;
    const uint32_t slot = awakeBodies[i];
    BodyRec& b = bodies.at(slot);
    SleepingIsland& is = islands[size_t(k)];
    is.bodies.push_back(slot);
    is.potential += -double(b.mass) * b.gravityScale *
                    (double(g.x) * b.com.x + double(g.y) * b.com.y + double(g.z) * b.com.z);
    b.v = b.w = {};
    b.island = k;
    b.solverIndex = 0;
    for (ShapeId sid : b.shapes) broadPhase.setStatic(shapes.get(sid)->proxy, true);
    deviceEdited(slot);  // goes up to the device asleep
    if (!b.joints.empty()) deviceJointsChanged();
    ++sleepingBodyCount;
  }
  for (int32_t k : sleepers) islands[size_t(k)].substepTime = stats.substepTime;
  sleepingPotentialValid = false;
  // Their contacts: those with points go with their island; the others between two bodies
  // that no longer move are dropped (the broad phase will not report them again). (A device
  // step's contacts are on the device, which simply finds no sleeping pairs; this list is
  // then the CPU's, from its last step.)
  contactScratch.clear();
  for (Contact& c : contacts) {
    const BodyRec& A = bodies.at(c.bodyA.index);
    const BodyRec& B = bodies.at(c.bodyB.index);
    if (A.awake() || B.awake()) {
      contactScratch.push_back(c);
    } else if (c.manifold.count > 0) {
      islands[size_t(A.asleep() ? A.island : B.island)].contacts.push_back(c);
    }
  }
  contacts.swap(contactScratch);
  awakeBodies.erase(std::remove_if(awakeBodies.begin(), awakeBodies.end(),
                                   [&](uint32_t slot) { return bodies.at(slot).asleep(); }),
                    awakeBodies.end());
  stats.sleepingIslands += int(sleepers.size());
  stats.sleepingBodies = sleepingBodyCount;
}

}  // namespace phys
