// The solver settings' list (PHYS_SOLVER_FIELDS) against the wire's SolverSettings table, a
// pinned format written by hand in physics.fbs: the same names in the same order, each field
// through the builder, the decoder and the converter on its own, and the bytes and the
// decoder's answers as they were before the list drove them.
#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include "../common/solver_fields.h"
#include "protocol_test_util.h"

namespace phys::protocol::test {
namespace {

using phys::solver_fields::kCount;
using phys::test::changedSettings;

TEST(SolverFields, ListIsTheWireTable) {
  std::vector<std::string> names;
#define PHYS_NAME(type, member, name, ...) names.push_back(#name);
  PHYS_SOLVER_FIELDS(PHYS_NAME)
#undef PHYS_NAME
  EXPECT_EQ(kCount, 27);
  EXPECT_EQ(names, schemaFields("SolverSettings"));
}

TEST(SolverFields, EachFieldAloneCrossesTheWire) {
  for (int i = -1; i < kCount; ++i) {  // -1: all of them
    const phys::SolverSettings want = changedSettings(i);
    SolverOverrides o = SolverOverrides::from(want);
    int n = 0;
#define PHYS_ONE(type, member, ...) \
  if (i >= 0 && n++ != i) o.member.reset();
    PHYS_SOLVER_FIELDS(PHYS_ONE)
#undef PHYS_ONE
    auto cmd = mustDecode(CommandBuilder().setSolver("", o).finish(header()));
    ASSERT_TRUE(cmd.ok());
    phys::SolverSettings got;
    applySolverSettings(*cmd->request_as_SetSolver()->settings(), &got);
    phys::test::expectSameSettings(got, want, "field " + std::to_string(i));
  }
}

/// A value of type T out of its range, from bad (-1, 1e9 or NaN); none for a flag, or NaN for
/// an integer.
template <class T>
std::optional<T> outside(double bad) {
  if constexpr (std::is_enum_v<T>)
    return std::isnan(bad) ? T(9) : T(bad < 0 ? 3 : 200);
  else if constexpr (std::is_same_v<T, bool>)
    return std::nullopt;
  else if (std::is_integral_v<T> && std::isnan(bad))
    return std::nullopt;
  else
    return T(bad);
}

// Pinned when the list came to drive the builder and the decoder (issue 44), over its first 27
// rows (rows appended later leave it be): the bytes of them all set, and the decoder's answer
// to each out of range (below, above, not finite) and to several at once.
TEST(SolverFields, BytesAndRangesAreAsBefore) {
  constexpr int kPinned = 27;
  const phys::SolverSettings changed = changedSettings();
  SolverOverrides set, all;
  std::string answers;
  auto answer = [&](const SolverOverrides& o) {
    answers += decodeCommand(CommandBuilder().setSolver("", o).finish(header())).status.message;
    answers += "\n";
  };
  int i = 0;
  for (double bad : {-1.0, 1e9, std::nan("")}) {
    i = 0;
#define PHYS_BAD(type, member, ...)                                             \
  if (i++ < kPinned) {                                                          \
    set.member = changed.member;                                                \
    if (auto v = outside<decltype(SolverOverrides::member)::value_type>(bad)) { \
      SolverOverrides o;                                                        \
      o.member = all.member = *v;                                               \
      answer(o);                                                                \
    }                                                                           \
  }
    PHYS_SOLVER_FIELDS(PHYS_BAD)
#undef PHYS_BAD
  }
  Bytes b = CommandBuilder().setSolver("", set).finish(header());
  EXPECT_EQ(fnv1a(std::string(b.begin(), b.end())), 4313864787903903143ull);
  // All out of range, then one fewer at a time: the first in the list's order is named.
  i = 0;
#define PHYS_DROP(type, member, ...) \
  if (i++ < kPinned) {               \
    answer(all);                     \
    all.member.reset();              \
  }
  PHYS_SOLVER_FIELDS(PHYS_DROP)
#undef PHYS_DROP
  EXPECT_EQ(fnv1a(answers), 3553462571819199005ull) << answers;
}

}  // namespace
}  // namespace phys::protocol::test
