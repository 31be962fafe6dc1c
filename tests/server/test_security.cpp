// DDS Security on loopback (issue 24, 4a; docs/SECURITY.md): physd's components in-process on
// configs/cyclonedds/secure.xml with identity "physd", and clients in processes of their own
// (this binary again, see runChildIfAsked: Cyclone has one configuration per domain and
// process, so a client with another identity, or none, needs a process of its own). The
// credentials are made once per test process by tools/make_security.sh into a temporary
// folder. A client of the same CA with a granted identity exchanges a command and its reply
// and reads status and state frames; a client without security (loopback.xml) or with a
// certificate of another CA reads nothing and gets nothing taken. On a secure daemon a world
// belongs to the identity that created it, not to a client id: another identity's edits are
// refused, the same identity from another process (another client id) may edit, and no
// participant can write in another identity's partition.
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <thread>

#include "phys/protocol/dds_envelope.h"
#include "phys/protocol/security.h"
#include "phys/server/dds.h"
#include "phys/server/endpoint.h"
#include "server_test_util.h"

namespace phys::server::test {
namespace {

namespace fs = std::filesystem;
using protocol::CommandBuilder;
using Clock = std::chrono::steady_clock;

const std::string kSource = PHYS_SOURCE_DIR;
const std::string kSecureXml = kSource + "/configs/cyclonedds/secure.xml";
const std::string kLoopbackXml = kSource + "/configs/cyclonedds/loopback.xml";
constexpr uint64_t kChildClient = 0x5EC0000ull;

std::string readAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// --- The client process -------------------------------------------------------------------
//
// Started with PHYS_SECTEST_XML (a Cyclone XML file), PHYS_SECTEST_DOMAIN, PHYS_SECTEST_WORLD
// and PHYS_SECTEST_SECONDS set (and PHYS_SECURITY_DIR / PHYS_IDENTITY for secure.xml), this
// binary is a client and never reaches GoogleTest's main: it joins the domain with that XML,
// writes a Hello every 250 ms whether or not a command reader is matched, reads phys/reply,
// phys/status and phys/state/<world>, and prints what it got as one line,
//   sectest matched=M replies=R hello_ok=H statuses=S states=F match_ms=T action=A world=W
// then exits 0 (3: it could not join the domain). It stops early once it has all three.
// Its commands go out in partition PHYS_SECTEST_PARTITION if set, else in its identity's
// (phys.id.<PHYS_IDENTITY>), else (or with "-") in the default partition. With PHYS_SECTEST_DO, once its
// Hello is answered it sends one more command and waits for its reply, A its status code:
//   create:NAME              CreateWorld NAME (W: the new world's id)
//   spawn:WORLD              SpawnBodies of one box into world WORLD
//   access:WORLD:IDENTITY    SetAccess of WORLD, editors = [identityKey(IDENTITY)]

struct ChildResult {
  bool ran = false;
  unsigned matched = 0;  ///< daemon readers/writers matched (command writer + reply reader)
  int replies = 0, helloOk = 0, statuses = 0, states = 0;
  /// What discovery showed it: other participants, and publications and subscriptions of
  /// other participants (topics); props: the property names of the participants' QoS.
  int participants = 0, endpoints = 0;
  std::string props;
  long matchMs = -1;
  int action = -1;  ///< PHYS_SECTEST_DO's reply status (-1: none came)
  uint32_t world = 0;
  std::string output;
};

/// PHYS_SECTEST_DO as a command (world id in *world).
protocol::Bytes actionCommand(const std::string& what, uint64_t id, uint64_t seq) {
  const size_t a = what.find(':'), b = what.find(':', a + 1);
  const std::string verb = what.substr(0, a), arg = what.substr(a + 1, b - a - 1);
  CommandBuilder c;
  if (verb == "create") {
    protocol::CreateWorldArgs args;
    args.name = arg;
    c.createWorld(args);
    return c.finish({id, seq, 0});
  }
  const uint32_t world = uint32_t(std::stoul(arg));
  if (verb == "spawn") {
    const std::vector<phys::BodyDef> bodies{boxBody({0, 0, 1})};
    c.spawnBodies(bodies);
  } else {
    const std::vector<uint64_t> editors{protocol::identityKey(what.substr(b + 1))};
    c.setAccess(editors, false);
  }
  return c.finish({id, seq, world});
}

int runChild(const char* xmlPath) {
  const uint32_t domain = uint32_t(std::atoi(std::getenv("PHYS_SECTEST_DOMAIN")));
  const uint32_t world = uint32_t(std::atoi(std::getenv("PHYS_SECTEST_WORLD")));
  const double seconds = std::atof(std::getenv("PHYS_SECTEST_SECONDS"));
  const char* action = std::getenv("PHYS_SECTEST_DO");
  std::vector<std::string> partitions;
  if (const char* p = std::getenv("PHYS_SECTEST_PARTITION")) {
    if (std::string(p) != "-") partitions.push_back(p);  // "-": the default partition
  }
  else if (const char* id = std::getenv("PHYS_IDENTITY"))
    partitions.push_back(protocol::identityPartition(id));
  std::string err;
  protocol::dds::Participant p;
  protocol::dds::Topic cmdTopic, replyTopic, statusTopic, stateTopic;
  protocol::dds::Writer cmd;
  protocol::dds::Reader replies, status, state;
  if (!p.create(domain, readAll(xmlPath), &err) || !cmdTopic.create(p, "phys/cmd", &err) ||
      !replyTopic.create(p, "phys/reply", &err) || !statusTopic.create(p, "phys/status", &err) ||
      !stateTopic.create(p, "phys/state/" + std::to_string(world), &err) ||
      !cmd.create(p, cmdTopic, protocol::kCommandQos, protocol::PayloadKind::Command, &err,
                  partitions) ||
      !replies.create(p, replyTopic, protocol::kReplyQos, &err) ||
      !status.create(p, statusTopic, protocol::kStatusQos, &err) ||
      !state.create(p, stateTopic, protocol::kStateQos, &err)) {
    std::printf("sectest error=%s\n", err.c_str());
    return 3;
  }
  // Discovery as the application sees it: the built-in topics.
  const dds_entity_t seenParticipants =
      dds_create_reader(p.get(), DDS_BUILTIN_TOPIC_DCPSPARTICIPANT, nullptr, nullptr);
  const dds_entity_t seenPublications =
      dds_create_reader(p.get(), DDS_BUILTIN_TOPIC_DCPSPUBLICATION, nullptr, nullptr);
  const dds_entity_t seenSubscriptions =
      dds_create_reader(p.get(), DDS_BUILTIN_TOPIC_DCPSSUBSCRIPTION, nullptr, nullptr);
  dds_guid_t own{};
  dds_get_guid(p.get(), &own);
  std::set<std::string> others, otherEndpoints, propNames;
  auto guidText = [](const dds_guid_t& g) { return std::string(g.v, g.v + 16); };
  auto readDiscovery = [&] {
    void* samples[16] = {};
    dds_sample_info_t infos[16];
    int n = dds_read(seenParticipants, samples, infos, 16, 16);
    for (int i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      auto* pp = static_cast<dds_builtintopic_participant_t*>(samples[i]);
      if (std::memcmp(pp->key.v, own.v, 16) == 0) continue;
      others.insert(guidText(pp->key));
      uint32_t np = 0;
      char** names = nullptr;
      if (pp->qos && dds_qget_propnames(pp->qos, &np, &names)) {
        for (uint32_t k = 0; k < np; ++k) {
          propNames.insert(names[k]);
          dds_free(names[k]);
        }
        dds_free(names);
      }
    }
    if (n > 0) dds_return_loan(seenParticipants, samples, n);
    for (dds_entity_t r : {seenPublications, seenSubscriptions}) {
      void* es[16] = {};
      n = dds_read(r, es, infos, 16, 16);
      for (int i = 0; i < n; ++i) {
        if (!infos[i].valid_data) continue;
        auto* e = static_cast<dds_builtintopic_endpoint_t*>(es[i]);
        if (std::memcmp(e->participant_key.v, own.v, 16) != 0)
          otherEndpoints.insert(guidText(e->key));
      }
      if (n > 0) dds_return_loan(r, es, n);
    }
  };
  const uint64_t id = kChildClient + uint64_t(getpid());
  int repliesSeen = 0, helloOk = 0, statuses = 0, states = 0, actionStatus = -1;
  uint32_t actionWorld = 0;
  uint64_t actionSeq = 0;
  long matchMs = -1;
  const auto start = Clock::now();
  const auto end = start + std::chrono::duration<double>(seconds);
  auto nextHello = start;
  uint64_t seq = 0;
  auto send = [&](const protocol::Bytes& b) {
    phys_wire_Envelope env{};
    protocol::wrapEnvelope(&env, id, seq, protocol::PayloadKind::Command, b);
    dds_write(cmd.get(), &env);
  };
  while (Clock::now() < end &&
         !(helloOk && statuses && states && (!action || actionStatus >= 0))) {
    if (matchMs < 0 && cmd.matched() > 0 && replies.matched() > 0)
      matchMs = long(std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - start)
                         .count());
    if (!helloOk && Clock::now() >= nextHello) {
      ++seq;
      send(CommandBuilder().hello("sectest").finish({id, seq, 0}));
      nextHello = Clock::now() + std::chrono::milliseconds(250);
    }
    if (helloOk && action && !actionSeq) {
      actionSeq = ++seq;
      send(actionCommand(action, id, actionSeq));
    }
    replies.take([&](const phys_wire_Envelope& env) {
      if (env.key != id) return;
      ++repliesSeen;
      auto bytes = protocol::envelopeBytes(env);
      Reply r = protocol::decodeReply(std::vector<uint8_t>(bytes.begin(), bytes.end()));
      if (!r.ok()) return;
      if (actionSeq && r->seq() == actionSeq) {
        actionStatus = int(r->status());
        actionWorld = r->world();
      } else if (r->status() == Code::Ok && r->result_as_HelloResult()) {
        helloOk = 1;
      }
    });
    status.take([&](const phys_wire_Envelope&) { ++statuses; });
    state.take([&](const phys_wire_Envelope&) { ++states; });
    readDiscovery();
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  std::string props;
  for (const std::string& n : propNames) props += (props.empty() ? "" : ",") + n;
  std::printf(
      "sectest matched=%u replies=%d hello_ok=%d statuses=%d states=%d match_ms=%ld action=%d "
      "world=%u participants=%zu endpoints=%zu props=%s\n",
      cmd.matched() + replies.matched(), repliesSeen, helloOk, statuses, states, matchMs,
      actionStatus, actionWorld, others.size(), otherEndpoints.size(),
      props.empty() ? "-" : props.c_str());
  return 0;
}

int runChildIfAsked() {
  const char* xml = std::getenv("PHYS_SECTEST_XML");
  if (!xml) return 0;
  const int rc = runChild(xml);  // its DDS entities are deleted when it returns
  std::fflush(stdout);
  std::_Exit(rc);
}
// Before main: a client process never starts GoogleTest.
[[maybe_unused]] const int kChild = runChildIfAsked();

std::string selfPath() {
  std::error_code ec;
  return fs::read_symlink("/proc/self/exe", ec).string();
}

std::string quoted(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

/// Runs this binary as a client (above) with these environment settings, for `seconds`.
ChildResult runClient(const std::string& xml, uint32_t domain, uint32_t world, double seconds,
                      const std::string& securityDir = "", const std::string& identity = "",
                      const std::string& action = "", const std::string& partition = "") {
  std::string cmd = "PHYS_SECTEST_XML=" + quoted(xml) +
                    " PHYS_SECTEST_DOMAIN=" + std::to_string(domain) +
                    " PHYS_SECTEST_WORLD=" + std::to_string(world) +
                    " PHYS_SECTEST_SECONDS=" + std::to_string(seconds);
  if (!securityDir.empty()) cmd += " PHYS_SECURITY_DIR=" + quoted(securityDir);
  if (!identity.empty()) cmd += " PHYS_IDENTITY=" + quoted(identity);
  if (!action.empty()) cmd += " PHYS_SECTEST_DO=" + quoted(action);
  if (!partition.empty()) cmd += " PHYS_SECTEST_PARTITION=" + quoted(partition);
  cmd += " exec " + quoted(selfPath());
  ChildResult r;
  FILE* f = popen(cmd.c_str(), "r");
  if (!f) return r;
  char line[512];
  while (std::fgets(line, sizeof line, f)) {
    r.output += line;
    char props[256] = {};
    if (std::sscanf(line,
                    "sectest matched=%u replies=%d hello_ok=%d statuses=%d states=%d "
                    "match_ms=%ld action=%d world=%u participants=%d endpoints=%d props=%255s",
                    &r.matched, &r.replies, &r.helloOk, &r.statuses, &r.states, &r.matchMs,
                    &r.action, &r.world, &r.participants, &r.endpoints, props) == 11) {
      r.ran = true;
      r.props = props;
    }
  }
  const int st = pclose(f);
  r.ran = r.ran && WIFEXITED(st) && WEXITSTATUS(st) == 0;
  return r;
}

// --- The credentials, once per process ----------------------------------------------------

struct Credentials {
  std::string skip;  ///< why the tests cannot run here; empty: they can
  fs::path dir;      ///< its main/ (physd, client1) and rogue/ (client1 of another CA)
};

const Credentials& credentials() {
  static const Credentials c = [] {
    Credentials c;
    if (std::system("command -v openssl > /dev/null 2>&1") != 0) {
      c.skip = "openssl is not installed (tools/make_security.sh needs it)";
      return c;
    }
    const char* env = std::getenv("PHYS_SECURITY_PLUGINS");
    const std::string plugins = env && *env ? env : "/usr/lib/x86_64-linux-gnu/libddsc0debian";
    for (const char* lib : {"auth", "ac", "crypto"}) {
      const std::string so = plugins + "/libdds_security_" + lib + ".so";
      if (!fs::exists(so)) {
        c.skip = "Cyclone's security plugin " + so +
                 " is missing (set PHYS_SECURITY_PLUGINS to their folder)";
        return c;
      }
    }
    c.dir = fs::temp_directory_path() / ("physd_security_" + std::to_string(getpid()));
    const std::string script = quoted(kSource + "/tools/make_security.sh");
    const std::string logFile = (c.dir / "make_security.log").string();
    fs::create_directories(c.dir);
    for (auto [sub, names] : {std::pair{"main", "physd client1 client2"}, std::pair{"rogue", "client1"}}) {
      const std::string run = "bash " + script + " --out " + quoted((c.dir / sub).string()) +
                              " --identities " + quoted(names) + " --days 2 >> " +
                              quoted(logFile) + " 2>&1";
      if (std::system(run.c_str()) != 0) {
        c.skip = "tools/make_security.sh failed: " + readAll(logFile);
        return c;
      }
    }
    return c;
  }();
  return c;
}

class ServerSecurity : public ::testing::Test {
 protected:
  void SetUp() override {
    const Credentials& c = credentials();
    if (!c.skip.empty()) GTEST_SKIP() << c.skip;
    mainDir = (c.dir / "main").string();
    rogueDir = (c.dir / "rogue").string();
    unsetenv("CYCLONEDDS_URI");
    // The daemon's identity: Cyclone expands these when the domain is made from secure.xml.
    setenv("PHYS_SECURITY_DIR", mainDir.c_str(), 1);
    setenv("PHYS_IDENTITY", "physd", 1);
  }
  static void TearDownTestSuite() {
    std::error_code ec;
    if (!credentials().dir.empty()) fs::remove_all(credentials().dir, ec);
  }
  std::string mainDir, rogueDir;
};

/// The daemon's components on secure.xml, with one running world (a box, never asleep; every
/// frame a keyframe) so that state frames flow to whoever may read them.
struct SecureDaemon {
  static CoreConfig config() {
    CoreConfig c = testConfig();
    c.keyframeTicks = 1;
    c.identities = true;
    return c;
  }
  explicit SecureDaemon(uint32_t domain)
      : core(config()), endpoint(&core, {domain, readAll(kSecureXml), /*identities=*/true}) {
    EXPECT_TRUE(core.init().ok());
    // Made before the endpoint and tick thread start (the test's thread is the tick thread
    // until then).
    CommandBuilder create;
    create.createWorld({"secure", "", phys::Vec3{0, 0, 0}, 0, "", /*sleep=*/false});
    Reply r = decode(core.applyBytes(create.finish({kClient, 1, 0}), kClient, 1));
    EXPECT_EQ(r->status(), Code::Ok) << message(r);
    world = r->world();
    CommandBuilder spawn;
    const std::vector<phys::BodyDef> bodies{boxBody({0, 0, 1})};
    spawn.spawnBodies(bodies);
    r = decode(core.applyBytes(spawn.finish({kClient, 2, world}), kClient, 2));
    EXPECT_EQ(r->status(), Code::Ok) << message(r);
    CommandBuilder run;
    run.run(20);
    r = decode(core.applyBytes(run.finish({kClient, 3, world}), kClient, 3));
    EXPECT_EQ(r->status(), Code::Ok) << message(r);
    Status s = endpoint.start();
    EXPECT_TRUE(s.ok()) << s.message;
    started = s.ok();
    tick.start();
  }
  ~SecureDaemon() {
    tick.stop();
    endpoint.stop();
  }
  ServerCore core;
  DdsEndpoint endpoint;
  uint32_t world = 0;
  bool started = false;
  TickThread tick{&core, std::chrono::milliseconds(200)};
};

uint32_t testDomain() {
  return 1 + uint32_t(getpid() % 200);  // within the documents' 0-230
}

// A client of the test CA with a granted identity (client1) is let in: Hello answered, status
// and state frames read.
void expectAdmitted(const ChildResult& r, const std::string& who) {
  ASSERT_TRUE(r.ran) << who << ": " << r.output;
  EXPECT_EQ(r.helloOk, 1) << who << ": " << r.output;
  EXPECT_GT(r.statuses, 0) << who << ": " << r.output;
  EXPECT_GT(r.states, 0) << who << ": " << r.output;
}

void expectRefused(const ChildResult& r, const SecureDaemon& d, const std::string& who) {
  ASSERT_TRUE(r.ran) << who << ": " << r.output;
  EXPECT_EQ(r.matched, 0u) << who << ": " << r.output;
  EXPECT_EQ(r.replies, 0) << who << ": " << r.output;
  EXPECT_EQ(r.statuses, 0) << who << ": " << r.output;
  EXPECT_EQ(r.states, 0) << who << ": " << r.output;
  EXPECT_EQ(d.endpoint.counters().commandsTaken.load(), 0u)
      << who << ": the daemon took a command from it";
}

TEST_F(ServerSecurity, ClientWithIdentityOfTheCaExchangesCommandsAndReadsStates) {
  const uint32_t domain = testDomain();
  SecureDaemon daemon(domain);
  ASSERT_TRUE(daemon.started);
  ChildResult r = runClient(kSecureXml, domain, daemon.world, 15, mainDir, "client1");
  expectAdmitted(r, "client1");
  EXPECT_GE(daemon.endpoint.counters().commandsTaken.load(), 1u);
  std::printf("client1: %s", r.output.c_str());
}

TEST_F(ServerSecurity, ClientWithoutCertificateIsRefused) {
  const uint32_t domain = testDomain();
  SecureDaemon daemon(domain);
  ASSERT_TRUE(daemon.started);
  // Plain loopback: no identity, no security. It writes Hellos for 4 s into nothing.
  ChildResult r = runClient(kLoopbackXml, domain, daemon.world, 4);
  expectRefused(r, daemon, "client without a certificate");
  // What it still sees (docs/SECURITY.md "What an outsider sees"): physd's participant in
  // discovery, whose announcement carries the tokens a handshake starts from, but no topic of
  // it: no publication, no subscription.
  EXPECT_GE(r.participants, 1) << r.output;
  EXPECT_EQ(r.endpoints, 0) << r.output;
  std::printf("client without a certificate: %s", r.output.c_str());
  // The daemon was there and serving all along: a client with an identity gets in.
  expectAdmitted(runClient(kSecureXml, domain, daemon.world, 15, mainDir, "client1"),
                 "client1 after");
}

TEST_F(ServerSecurity, ClientWithCertificateOfAnotherCaIsRefused) {
  const uint32_t domain = testDomain();
  SecureDaemon daemon(domain);
  ASSERT_TRUE(daemon.started);
  // Same identity name and subject (CN=client1,O=physd-test), same secure.xml, but its CA,
  // governance and permissions are another CA's: the handshake fails both ways.
  ChildResult r = runClient(kSecureXml, domain, daemon.world, 4, rogueDir, "client1");
  expectRefused(r, daemon, "client of another CA");
  expectAdmitted(runClient(kSecureXml, domain, daemon.world, 15, mainDir, "client1"),
                 "client1 after");
}

TEST_F(ServerSecurity, ClientWithOwnCertificateButForeignDocumentsCannotStart) {
  // A certificate of the test CA with governance and permissions signed by another CA does
  // not make a participant at all: Cyclone checks its own documents against its CA first.
  fs::path mixed = credentials().dir / "mixed";
  fs::create_directories(mixed);
  for (const char* f : {"ca_cert.pem", "client1_cert.pem", "client1_key.pem"})
    fs::copy_file(fs::path(mainDir) / f, mixed / f, fs::copy_options::overwrite_existing);
  for (const char* f : {"governance.p7s", "permissions.p7s"})
    fs::copy_file(fs::path(rogueDir) / f, mixed / f, fs::copy_options::overwrite_existing);
  ChildResult r = runClient(kSecureXml, testDomain(), 1, 2, mixed.string(), "client1");
  EXPECT_FALSE(r.ran) << r.output;
  EXPECT_NE(r.output.find("sectest error="), std::string::npos) << r.output;
}

TEST_F(ServerSecurity, AWorldBelongsToTheIdentityThatCreatedItNotToAClientId) {
  const uint32_t domain = testDomain();
  SecureDaemon daemon(domain);
  ASSERT_TRUE(daemon.started);
  auto as = [&](const char* identity, const std::string& action) {
    ChildResult r = runClient(kSecureXml, domain, daemon.world, 20, mainDir, identity, action);
    EXPECT_TRUE(r.ran && r.helloOk) << identity << " " << action << ": " << r.output;
    return r;
  };
  // client1 creates a world; each child process has a client id of its own (its pid).
  ChildResult made = as("client1", "create:owned");
  ASSERT_EQ(made.action, int(Code::Ok)) << made.output;
  const std::string world = std::to_string(made.world);
  // Another identity may not change it; client1 from another process (another client id) may.
  EXPECT_EQ(as("client2", "spawn:" + world).action, int(Code::PermissionDenied));
  EXPECT_EQ(as("client1", "spawn:" + world).action, int(Code::Ok));
  // The owner names client2 an editor by identity: now it may.
  EXPECT_EQ(as("client1", "access:" + world + ":client2").action, int(Code::Ok));
  EXPECT_EQ(as("client2", "spawn:" + world).action, int(Code::Ok));
  // Commands outside an identity partition are refused on a secure daemon, Hello too (physd's
  // own identity may publish anywhere, so its participant can try).
  ChildResult plain = runClient(kSecureXml, domain, daemon.world, 4, mainDir, "physd", "", "-");
  ASSERT_TRUE(plain.ran) << plain.output;
  EXPECT_GT(plain.replies, 0) << plain.output;
  EXPECT_EQ(plain.helloOk, 0) << plain.output;
  EXPECT_GT(daemon.endpoint.counters().unidentified.load(), 0u);
  // No participant can write in another identity's partition: client2's permissions refuse
  // a writer in phys.id.client1 (its own access-control plugin, and physd's for remote ones).
  ChildResult forged = runClient(kSecureXml, domain, daemon.world, 4, mainDir, "client2",
                                 "spawn:" + world, protocol::identityPartition("client1"));
  EXPECT_FALSE(forged.ran) << forged.output;
  EXPECT_NE(forged.output.find("sectest error="), std::string::npos) << forged.output;
}

}  // namespace
}  // namespace phys::server::test
