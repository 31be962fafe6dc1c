#include "dynamics/joints.h"

#include <algorithm>
#include <cmath>
#include <functional>

namespace phys {

JointFrame jointFrame(const JointRec& j, const BodyPose* A, const BodyPose& B) {
  JointFrame f;
  if (A) {
    f.qA = A->q;
    f.rA = rotate(f.qA, j.def.anchorA - A->localCenter);
    f.pA = A->com + f.rA;
  } else {
    f.rA = j.def.anchorA;
    f.pA = j.def.anchorA;
  }
  f.qB = B.q;
  f.rB = rotate(f.qB, j.def.anchorB - B.localCenter);
  f.pB = B.com + f.rB;
  return f;
}

void initJoint(JointRec& j, const BodyPose* A, const BodyPose& B) {
  JointFrame f = jointFrame(j, A, B);
  j.relRot0 = conjugate(f.qA) * f.qB;
  Vec3 axisA = normalize(j.def.axisA);
  Vec3 t1, t2;
  tangentBasis(axisA, &t1, &t2);
  j.refA = t1;
  // B's reference is A's, carried into B's frame at the creation pose: the hinge angle is 0 now.
  j.refB = invRotate(f.qB, rotate(f.qA, t1));
  float len = length(f.pB - f.pA);
  j.length = j.def.length >= 0 ? j.def.length : len;
}

namespace {

/// The rotation of B relative to its creation-time pose seen from A, as a world rotation vector.
Vec3 relativeRotationError(const JointRec& j, const JointFrame& f) {
  return rotationVector(normalize(f.qB * conjugate(f.qA * j.relRot0)));
}

struct RowBuilder {
  Solver* solver;
  int32_t ia, ib;
  Vec3 rA, rB;

  /// A row acting on the anchor points along direction e (leverA overrides rA).
  Row& linear(RowKind kind, Vec3 e, float C, Vec3 leverA) {
    Row r;
    r.kind = kind;
    r.a = ia;
    r.b = ib;
    r.linA = -e;
    r.angA = -cross(leverA, e);
    r.linB = e;
    r.angB = cross(rB, e);
    r.C0 = C;
    solver->rows.push_back(r);
    return solver->rows.back();
  }
  Row& linear(RowKind kind, Vec3 e, float C) { return linear(kind, e, C, rA); }
  /// A row on the relative angular velocity about u.
  Row& angular(RowKind kind, Vec3 u, float C) {
    Row r;
    r.kind = kind;
    r.a = ia;
    r.b = ib;
    r.angA = -u;
    r.angB = u;
    r.C0 = C;
    solver->rows.push_back(r);
    return solver->rows.back();
  }
};

/// Limit rows (position within [lower, upper]) and a motor row along dir, for hinges and sliders.
void addLimitAndMotor(const JointDef& d, float position, float h,
                      const std::function<Row&(RowKind, Vec3, float)>& add, Vec3 dir) {
  if (d.enableLimit) {
    add(RowKind::Limit, dir, position - d.lower);
    add(RowKind::Limit, -dir, d.upper - position);
  }
  if (d.enableMotor) {
    Row& m = add(RowKind::Motor, dir, 0);
    m.target = d.motorSpeed;
    m.maxImpulse = d.maxMotorForce * h;
  }
}

}  // namespace

void buildJointRows(JointRec& j, const BodyPose* A, const BodyPose& B, int32_t ia, int32_t ib,
                    float h, Solver* solver) {
  const JointDef& d = j.def;
  JointFrame f = jointFrame(j, A, B);
  Vec3 dp = f.pB - f.pA;
  RowBuilder rb{solver, ia, ib, f.rA, f.rB};
  j.firstRow = int32_t(solver->rows.size());
  const Vec3 ex{1, 0, 0}, ey{0, 1, 0}, ez{0, 0, 1};
  auto markBlock = [&](size_t first) {
    solver->rows[first].blockSize = uint8_t(solver->rows.size() - first);
  };
  auto pointRows = [&] {
    size_t first = solver->rows.size();
    rb.linear(RowKind::Equality, ex, dp.x);
    rb.linear(RowKind::Equality, ey, dp.y);
    rb.linear(RowKind::Equality, ez, dp.z);
    markBlock(first);
  };
  auto lockRotation = [&] {
    Vec3 e = relativeRotationError(j, f);
    size_t first = solver->rows.size();
    rb.angular(RowKind::Equality, ex, e.x);
    rb.angular(RowKind::Equality, ey, e.y);
    rb.angular(RowKind::Equality, ez, e.z);
    markBlock(first);
  };

  switch (d.type) {
    case JointType::Ball:
      pointRows();
      break;
    case JointType::Fixed:
      pointRows();
      lockRotation();
      break;
    case JointType::Hinge: {
      pointRows();
      Vec3 aA = rotate(f.qA, normalize(d.axisA));
      Vec3 aB = rotate(f.qB, normalize(d.axisB));
      Vec3 b1, b2;
      tangentBasis(aA, &b1, &b2);
      // Small-angle misalignment of the axes: (aA x aB) projected on the two perpendiculars.
      Vec3 mis = cross(aA, aB);
      size_t first = solver->rows.size();
      rb.angular(RowKind::Equality, b1, dot(b1, mis));
      rb.angular(RowKind::Equality, b2, dot(b2, mis));
      markBlock(first);
      Vec3 rfA = rotate(f.qA, j.refA), rfB = rotate(f.qB, j.refB);
      float angle = std::atan2(dot(cross(rfA, rfB), aA), dot(rfA, rfB));
      addLimitAndMotor(
          d, angle, h, [&](RowKind k, Vec3 u, float C) -> Row& { return rb.angular(k, u, C); }, aA);
      break;
    }
    case JointType::Prismatic: {
      Vec3 a = rotate(f.qA, normalize(d.axisA));
      Vec3 b1, b2;
      tangentBasis(a, &b1, &b2);
      // A's lever reaches to B's anchor, so sliding along the axis changes no perpendicular row.
      Vec3 leverA = f.rA + dp;
      size_t first = solver->rows.size();
      rb.linear(RowKind::Equality, b1, dot(b1, dp), leverA);
      rb.linear(RowKind::Equality, b2, dot(b2, dp), leverA);
      markBlock(first);
      lockRotation();
      addLimitAndMotor(
          d, dot(a, dp), h,
          [&](RowKind k, Vec3 u, float C) -> Row& { return rb.linear(k, u, C, leverA); }, a);
      break;
    }
    case JointType::Distance: {
      float len = length(dp);
      Vec3 n = len > 1e-6f ? dp / len : ex;
      bool rigid = !d.enableLimit && d.springHertz <= 0;
      if (rigid) rb.linear(RowKind::Equality, n, len - j.length);
      if (d.springHertz > 0) {
        Row& s = rb.linear(RowKind::Spring, n, len - j.length);
        s.hertz = d.springHertz;
        s.dampingRatio = d.springDampingRatio;
      }
      if (d.enableLimit) {
        rb.linear(RowKind::Limit, n, len - d.lower);
        rb.linear(RowKind::Limit, -n, d.upper - len);
      }
      break;
    }
  }
  j.rowCount = int32_t(solver->rows.size()) - j.firstRow;
  if (j.rowCount > 0) solver->rows[size_t(j.firstRow)].groupStart = true;
}

void refreshJointRows(JointRec& j, const BodyPose* A, const BodyPose& B, int32_t ia, int32_t ib,
                      float h, Solver* solver) {
  const int32_t first = j.firstRow, count = j.rowCount;
  const size_t end = solver->rows.size();
  buildJointRows(j, A, B, ia, ib, h, solver);
  // Same joint, same settings: the same rows in the same order. Move them into place.
  for (int32_t k = 0; k < count && size_t(k) + end < solver->rows.size(); ++k) {
    Row& dst = solver->rows[size_t(first + k)];
    Row fresh = solver->rows[end + size_t(k)];
    fresh.lambda = dst.lambda;
    fresh.blockIndex = dst.blockIndex;
    // rowError adds J . delta; subtract it now so the error starts from the exact value.
    const SolverBody& sa = solver->bodies[size_t(fresh.a)];
    const SolverBody& sb = solver->bodies[size_t(fresh.b)];
    fresh.C0 -= dot(fresh.linA, sa.dp) + dot(fresh.angA, sa.dtheta) + dot(fresh.linB, sb.dp) +
                dot(fresh.angB, sb.dtheta);
    dst = fresh;
  }
  solver->rows.resize(end);
  j.firstRow = first;
  j.rowCount = count;
  solver->finishRows(size_t(first), size_t(first + count));
}

void measureJoint(const JointRec& j, const BodyPose* A, const BodyPose& B, float* positionError,
                  float* angleError) {
  const JointDef& d = j.def;
  JointFrame f = jointFrame(j, A, B);
  Vec3 dp = f.pB - f.pA;
  float pos = 0, ang = 0;
  switch (d.type) {
    case JointType::Ball:
      pos = length(dp);
      break;
    case JointType::Fixed:
      pos = length(dp);
      ang = length(relativeRotationError(j, f));
      break;
    case JointType::Hinge: {
      pos = length(dp);
      Vec3 aA = rotate(f.qA, normalize(d.axisA));
      Vec3 aB = rotate(f.qB, normalize(d.axisB));
      ang = std::atan2(length(cross(aA, aB)), dot(aA, aB));
      break;
    }
    case JointType::Prismatic: {
      Vec3 a = rotate(f.qA, normalize(d.axisA));
      pos = length(dp - a * dot(a, dp));
      ang = length(relativeRotationError(j, f));
      break;
    }
    case JointType::Distance: {
      float len = length(dp);
      if (!d.enableLimit && d.springHertz <= 0) pos = std::fabs(len - j.length);
      if (d.enableLimit) pos = std::max({pos, d.lower - len, len - d.upper, 0.0f});
      break;
    }
  }
  *positionError = pos;
  *angleError = ang;
}

}  // namespace phys
