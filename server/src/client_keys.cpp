// ClientKeys: client ids bound to DDS participants (phys/server/client_keys.h).
#include "phys/server/client_keys.h"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <unordered_set>

namespace phys::server {

size_t GuidHash::operator()(const Guid& g) const noexcept {
  // The prefix is random per participant (Cyclone: host, process and a counter mixed in), and
  // the entity id adds little: a 64-bit mix of both halves.
  uint64_t a = 0, b = 0;
  std::memcpy(&a, g.data(), 8);
  std::memcpy(&b, g.data() + 8, 8);
  uint64_t h = a * 0x9E3779B97F4A7C15ull ^ (b + 0x632BE59BD9B4E019ull + (a << 6) + (a >> 2));
  h ^= h >> 31;
  return size_t(h * 0xBF58476D1CE4E5B9ull);
}

std::string toString(const Guid& g) {
  char s[40];
  uint32_t w[4];
  for (int i = 0; i < 4; ++i)
    w[i] = uint32_t(g[4 * i]) << 24 | uint32_t(g[4 * i + 1]) << 16 | uint32_t(g[4 * i + 2]) << 8 |
           g[4 * i + 3];
  std::snprintf(s, sizeof s, "%x:%x:%x:%x", w[0], w[1], w[2], w[3]);
  return s;
}

const char* ClientKeys::toString(Verdict v) {
  switch (v) {
    case Verdict::Ok: return "ok";
    case Verdict::HeldByOther: return "held by another participant";
    case Verdict::TooManyKeys: return "too many client ids for one participant";
    case Verdict::Full: return "client id table full";
  }
  return "?";
}

ClientKeys::ClientKeys(Limits limits, Alive alive) : limits_(limits), alive_(std::move(alive)) {
  limits_.keysPerParticipant = std::max<uint32_t>(1, limits_.keysPerParticipant);
}

bool ClientKeys::addWriter(Writer w, const Guid& participant, uint64_t principal) {
  if (writers_.count(w)) return true;
  if (writers_.size() >= limits_.maxWriters) {
    sweepWanted_ = true;
    return false;
  }
  auto [g, added] = byGuid_.try_emplace(participant, nextParticipant_);
  if (added) {
    ParticipantRec p;
    p.guid = participant;
    participants_.emplace(nextParticipant_++, std::move(p));
  }
  ++participants_.at(g->second).writers;
  writers_.emplace(w, WriterRec{g->second, principal});
  return true;
}

ClientKeys::Result ClientKeys::refuse(Verdict v, uint64_t participant, uint64_t principal,
                                      Clock::time_point now) {
  Result r;
  r.verdict = v;
  r.participant = participant;
  r.principal = principal;
  auto p = participants_.find(participant);
  if (p == participants_.end()) return r;
  r.refusals = ++p->second.refusals;
  if (r.refusals == 1 || now - p->second.reportedAt >= limits_.reportEvery) {
    r.report = true;
    p->second.reportedAt = now;
  }
  return r;
}

bool ClientKeys::proves(ParticipantRec& p, const Proof* proof, Clock::time_point now) {
  if (!proof || !*proof) return false;
  // The participant's budget of signature checks: a token bucket.
  const double elapsed = std::chrono::duration<double>(now - p.proofAt).count();
  p.proofTokens = p.proofTokens < 0 ? limits_.proofBurst
                                    : std::min(limits_.proofBurst,
                                               p.proofTokens + elapsed * limits_.proofsPerSecond);
  p.proofAt = now;
  if (p.proofTokens < 1) return false;
  p.proofTokens -= 1;
  return (*proof)(p.guid);
}

ClientKeys::Result ClientKeys::claim(uint64_t key, Writer writer, Clock::time_point now,
                                     const Proof* proof) {
  auto w = writers_.find(writer);
  if (w == writers_.end()) {  // not added (the writer table is full)
    Result r;
    r.verdict = Verdict::Full;
    sweepWanted_ = true;
    return r;
  }
  const uint64_t who = w->second.participant;
  const uint64_t principal = w->second.principal;
  auto k = keys_.find(key);
  if (k != keys_.end()) {
    KeyRec& held = k->second;
    ParticipantRec& p = participants_.at(who);
    if (held.participant == who) {
      held.writer = writer;
      if (!held.proven && proves(p, proof, now)) held.proven = true;
      return Result{Verdict::Ok, who, principal, false, 0, held.proven};
    }
    // Another participant holds it. A proof takes it at once (the holder, proven or not, is
    // the key's holder no more: two proofs of one key are the same client, the newest wins);
    // without one, only once its holder left (a client restarted with a plain fixed id).
    const bool proven = proves(p, proof, now);
    if (!proven && !mayTake(held, who, now))
      return refuse(Verdict::HeldByOther, who, principal, now);
    if (p.keys.size() >= limits_.keysPerParticipant)
      return refuse(Verdict::TooManyKeys, who, principal, now);
    auto old = participants_.find(held.participant);
    if (old != participants_.end()) release(old->second, key);
    held = KeyRec{who, writer, {}, proven};
    p.keys.push_back(key);
    return Result{Verdict::Ok, who, principal, false, 0, proven};
  }
  ParticipantRec& p = participants_.at(who);
  if (p.keys.size() >= limits_.keysPerParticipant)
    return refuse(Verdict::TooManyKeys, who, principal, now);
  if (keys_.size() >= limits_.maxKeys) {
    sweepWanted_ = true;
    return refuse(Verdict::Full, who, principal, now);
  }
  const bool proven = proves(p, proof, now);
  keys_.emplace(key, KeyRec{who, writer, {}, proven});
  p.keys.push_back(key);
  return Result{Verdict::Ok, who, principal, false, 0, proven};
}

bool ClientKeys::mayTake(KeyRec& held, uint64_t /*claimant*/, Clock::time_point now) {
  // The holder is there while DDS matches the writer that last used the key; asked at most
  // once per recheck (between, the sweep keeps the answer honest).
  if (held.checkedAt != Clock::time_point{} && now - held.checkedAt < limits_.recheck)
    return false;
  held.checkedAt = now;
  return !alive_(held.writer);
}

void ClientKeys::release(ParticipantRec& p, uint64_t key) {
  auto it = std::find(p.keys.begin(), p.keys.end(), key);
  if (it != p.keys.end()) {
    *it = p.keys.back();
    p.keys.pop_back();
  }
}

std::vector<ClientKeys::Departed> ClientKeys::sweep(std::span<const Writer> live) {
  sweepWanted_ = false;
  const std::unordered_set<Writer> matched(live.begin(), live.end());
  std::vector<Departed> gone;
  for (auto it = writers_.begin(); it != writers_.end();) {
    if (matched.count(it->first)) {
      ++it;
      continue;
    }
    const uint64_t who = it->second.participant;
    it = writers_.erase(it);
    auto p = participants_.find(who);
    if (p == participants_.end() || --p->second.writers > 0) continue;
    Departed d;
    d.participant = who;
    d.guid = p->second.guid;
    d.keys = std::move(p->second.keys);
    for (uint64_t key : d.keys) keys_.erase(key);
    byGuid_.erase(p->second.guid);
    participants_.erase(p);
    gone.push_back(std::move(d));
  }
  return gone;
}

uint64_t ClientKeys::holder(uint64_t key) const {
  auto it = keys_.find(key);
  return it == keys_.end() ? 0 : it->second.participant;
}

const Guid* ClientKeys::guidOf(uint64_t participant) const {
  auto it = participants_.find(participant);
  return it == participants_.end() ? nullptr : &it->second.guid;
}

uint64_t ClientKeys::participantOf(Writer w) const {
  auto it = writers_.find(w);
  return it == writers_.end() ? 0 : it->second.participant;
}

size_t ClientKeys::keysOf(uint64_t participant) const {
  auto it = participants_.find(participant);
  return it == participants_.end() ? 0 : it->second.keys.size();
}

// --- InstanceGate ---------------------------------------------------------------------------

bool InstanceGate::admit(uint64_t writer, uint64_t instance, Clock::time_point now) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto [it, added] = writers_.try_emplace(writer);
  WriterRec& w = it->second;
  if (added) {
    w.tokens = std::max(1.0, limits_.burst);
    w.last = now;
  }
  if (std::find(w.instances.begin(), w.instances.end(), instance) == w.instances.end()) {
    if (w.instances.size() >= limits_.instances) {
      ++w.refusedInstances;
      ++refused_;
      return false;
    }
    w.instances.push_back(instance);
  }
  if (limits_.rate > 0) {
    w.tokens = std::min(std::max(1.0, limits_.burst),
                        w.tokens + std::chrono::duration<double>(now - w.last).count() *
                                       limits_.rate);
    w.last = now;
    if (w.answered) {  // its last command answered: one request in flight is no flood
      w.answered = false;
      return true;
    }
    if (w.tokens < 1) {
      ++w.refusedRate;
      ++refused_;
      return false;
    }
    w.tokens -= 1;
  }
  return true;
}

void InstanceGate::bind(uint64_t writer, uint64_t key) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto k = keyWriters_.find(key);
  if (k != keyWriters_.end() && k->second == writer) return;  // the usual case
  auto it = writers_.find(writer);
  if (it == writers_.end()) return;  // swept meanwhile
  WriterRec& w = it->second;
  if (std::find(w.keys.begin(), w.keys.end(), key) == w.keys.end()) {
    if (w.keys.size() >= limits_.instances) return;
    w.keys.push_back(key);
  }
  keyWriters_[key] = writer;  // the key's holder now (another participant may have had it)
}

void InstanceGate::answered(uint64_t key) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto k = keyWriters_.find(key);
  if (k == keyWriters_.end()) return;
  auto it = writers_.find(k->second);
  if (it != writers_.end()) it->second.answered = true;
}

std::vector<InstanceGate::Refused> InstanceGate::sweep(std::span<const uint64_t> live,
                                                        Clock::time_point now) {
  const std::unordered_set<uint64_t> matched(live.begin(), live.end());
  std::vector<Refused> out;
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto it = writers_.begin(); it != writers_.end();) {
    WriterRec& w = it->second;
    const uint64_t refused = w.refusedInstances + w.refusedRate;
    if (refused > w.reported && (w.reported == 0 || now - w.reportedAt >= limits_.reportEvery)) {
      out.push_back({it->first, w.refusedInstances, w.refusedRate});
      w.reported = refused;
      w.reportedAt = now;
    }
    if (matched.count(it->first)) {
      ++it;
      continue;
    }
    for (uint64_t key : w.keys) {
      auto k = keyWriters_.find(key);
      if (k != keyWriters_.end() && k->second == it->first) keyWriters_.erase(k);
    }
    it = writers_.erase(it);
  }
  return out;
}

uint64_t InstanceGate::refused() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return refused_;
}

size_t InstanceGate::writers() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return writers_.size();
}

}  // namespace phys::server
