// Written once, read by both sides: the GPU step's buffer records, push constants and
// workgroup sizes. GLSL includes this file (GL_GOOGLE_include_directive), C++ includes it
// through phys/gpu/shared.h, which checks every size with static_assert.
//
// Rules (std430 in GLSL, plain structs in C++): members are vec4/uvec4/float/uint/int only,
// no vec3 (its std430 alignment is 16 but its size 12, which C++ does not reproduce), and
// every record is a multiple of 16 bytes.
#ifndef PHYS_GPU_SHARED_H
#define PHYS_GPU_SHARED_H

#ifdef __cplusplus
#include <cstdint>
namespace phys::gpu {
struct vec4 {
  float x = 0, y = 0, z = 0, w = 0;
};
struct uvec4 {
  uint32_t x = 0, y = 0, z = 0, w = 0;
};
using uint = uint32_t;
#endif

// Workgroup size of every one-thread-per-item kernel.
#define PHYS_GPU_GROUP 64
// Values per workgroup of the prefix sum (scan_local.comp, scan_add.comp).
#define PHYS_GPU_SCAN_GROUP 256
// Keys per workgroup of the bitonic sort's shared-memory passes (bitonic_local.comp).
#define PHYS_GPU_SORT_TILE 512

// GpuBodyParams.flags bits.
#define PHYS_GPU_BODY_DYNAMIC 1u     // moved by forces and constraints (else kinematic)
#define PHYS_GPU_BODY_GYROSCOPIC 2u  // unequal principal moments: the free-rotation splitting
// Asleep (an island at rest, physics/world/islands.cpp): not dynamic, not moved, makes no
// pairs with static or other sleeping bodies; an awake body touching it wakes it (the host).
#define PHYS_GPU_BODY_ASLEEP 4u

// GpuShape.type, as phys::ShapeType.
#define PHYS_GPU_SHAPE_SPHERE 0u
#define PHYS_GPU_SHAPE_BOX 1u
#define PHYS_GPU_SHAPE_CAPSULE 2u
#define PHYS_GPU_SHAPE_PLANE 3u
#define PHYS_GPU_SHAPE_HULL 4u

// A body's state: what the step advances and what comes back for publishing. One per
// non-static body, in the host's order (GpuWorld's body index).
struct GpuBodyState {
  vec4 com;  // xyz: centre of mass in the world (m); w: unused
  vec4 q;    // orientation (x, y, z, w), body frame -> world
  vec4 v;    // xyz: linear velocity (m/s)
  vec4 w;    // xyz: angular velocity (rad/s, world)
};

// What the integration needs beside the state; uploaded when a body is edited.
struct GpuBodyParams {
  vec4 accel;          // xyz: gravity * scale + force / mass (m/s^2); w: inverse mass
  vec4 torque;         // xyz: applied torque (N m); w: linear damping (1/s)
  vec4 principal;      // principal-axes frame -> body frame (quaternion)
  vec4 moments;        // xyz: principal moments (kg m^2); w: angular damping (1/s)
  vec4 invInertia[3];  // rows of the inverse inertia about the centre of mass, body axes
  vec4 localCenter;    // xyz: centre of mass in the body frame; w: geometric stiffness of
                       // its joints (N m/rad, from last step's joint forces; 0: none)
  uvec4 flags;         // x: PHYS_GPU_BODY_* bits
};

// The solver's view of a body during the step (substeps): velocity, the displacement since
// the step began and the current orientation.
struct GpuSolverBody {
  vec4 v;       // xyz linear velocity
  vec4 w;       // xyz angular velocity
  vec4 dp;      // xyz: centre-of-mass displacement since the step began (m)
  vec4 q;       // current orientation
  vec4 dtheta;  // xyz: accumulated rotation vector since the step began (rad)
  vec4 invI[3];  // rows of the world inverse inertia at the step's start
};

// A shape for the collision stages: its body (GpuWorld body index, or -1 for static
// geometry held in the world frame), its frame, its geometry and its material.
struct GpuShape {
  vec4 localP;  // xyz: position in the body frame; w: bounding radius about the body's com
  vec4 localQ;  // orientation in the body frame
  vec4 size;    // sphere: (r); box: (hx, hy, hz); capsule: (r, half height); plane: (nx, ny, nz, d)
  int body;     // GpuWorld body index, -1: static (localP/localQ are then world)
  uint type;    // PHYS_GPU_SHAPE_*
  float friction;
  float restitution;
};

// World-space bounds of a shape, fattened by the speculative margin.
struct GpuAabb {
  vec4 lo;  // xyz; w: unused
  vec4 hi;  // xyz; w: unused
};

// A candidate pair from the broad phase: shapes a < b (GpuWorld shape indices).
struct GpuPair {
  uint a;
  uint b;
  uint pad0;
  uint pad1;
};

// A contact manifold, as phys::Manifold: up to 4 points sharing one normal. One per pair
// (same index); count 0 when the shapes are apart by more than the margin.
struct GpuManifold {
  vec4 normal;       // xyz: unit normal from shape A to shape B; w: mixed friction
  vec4 points[4];    // xyz: world point midway between the surfaces; w: separation (m)
  uvec4 featureIds;  // per point, the layout of physics/collision/collide_internal.h
  uint count;        // 0..4
  uint shapeA;       // = the pair's a
  uint shapeB;       // = the pair's b
  float restitution;  // mixed: max of the two
  vec4 normalImpulse;    // per point: last step's impulse (warm start) in, this step's out
  vec4 tangentImpulse1;  // per point, along the first tangent
  vec4 tangentImpulse2;  // per point, along the second tangent
};

// Counters the stages write on the device (a uint array); the host reads them back.
#define PHYS_GPU_COUNTER_PAIRS 0u       // candidate pairs the broad phase found (at most the capacity)
#define PHYS_GPU_COUNTER_OVERFLOW 1u    // pairs beyond the pair buffers' capacity (then dropped)
#define PHYS_GPU_COUNTER_PREV_PAIRS 2u  // the previous step's pairs (its manifolds, for warm starts)
#define PHYS_GPU_COUNTER_CONTACTS 3u    // manifolds with points
#define PHYS_GPU_COUNTER_POINTS 4u      // contact points
#define PHYS_GPU_COUNTER_DEEPEST 5u     // the deepest penetration (m), as float bits (>= 0)
#define PHYS_GPU_COUNTER_COLORS 6u      // colors the coloring used (the overflow not counted)
// The broad phase's candidate tests (box-against-box tests its query made, planes not
// counted) as a 64-bit count: low word, then high word (bvh_count.comp, bp_count.comp).
#define PHYS_GPU_COUNTER_BP_TESTS 7u
#define PHYS_GPU_COUNTER_BP_TESTS_HI 8u
#define PHYS_GPU_COUNTER_COUNT 12u

// The broad phase's tree (a linear BVH over the non-plane shapes, bvh_build.comp): internal
// node i of the L - 1; its children are internal nodes or leaves (PHYS_GPU_BVH_LEAF set: the
// shape at that position of the Morton-sorted keys, whose box is in the leaf array).
#define PHYS_GPU_BVH_LEAF 0x80000000u
#define PHYS_GPU_BVH_NONE 0xFFFFFFFFu
// The query's stack: one entry per level at most, and a Karras tree over 30-bit Morton codes
// tie-broken by 32-bit positions is at most 63 levels deep.
#define PHYS_GPU_BVH_STACK 64
struct GpuBvhNode {
  vec4 lo;    // xyz: the box of every shape below; w: 1 if a dynamic shape is below, else 0
  vec4 hi;    // xyz; w: unused
  uvec4 link; // x, y: the children; z: the last sorted position below (the query skips
              // subtrees wholly at or before its own); w: unused
};

// Push constants of the step's stages.
struct GpuStepConstants {
  float h;                    // s, substep length
  float dt;                   // s, step length
  float maxLinearSpeed;       // m/s
  float maxAngularSpeed;      // rad/s
  float speculativeDistance;  // m: contact points closer than this (plus the bodies' reach) are kept
  uint sweepAxis;             // broad phase: the axis (0, 1, 2) the bounds are sorted and swept on
  float pad1;
  float pad2;
  uint bodyCount;
  uint shapeCount;
  uint pairCapacity;    // pairs the pair and manifold buffers hold (a power of two)
  uint planeCount;      // static planes (the broad phase pairs them with every shape below them)
  uint shapeSortCount;  // length of the broad phase's key sort (a power of two >= shapeCount)
  uint patchFriction;   // warm starts keep a manifold's friction while any point persists
  uint noCollideCount;  // body pairs joined without collide_connected (the broad phase skips them)
  uint splitPushout;    // integrate_positions: positions also move by the push-out velocities
};

// The solver's view of one manifold (index = its pair's): the rows of its points, as the
// CPU's contact rows (World::Impl::contactRowsOf): a normal row per point, then a friction
// pair per point along t1 and t2. Built by prepare_contacts.comp; lambdas are the
// accumulated impulses of the current substep.
struct GpuContact {
  int bodyA;      // GpuWorld body index, -1: static (no velocity, no mass)
  int bodyB;
  uint count;     // points, 0..4 (0: nothing to solve)
  float friction;
  vec4 normal;    // xyz: from A to B; w: restitution
  vec4 t1;        // xyz: first tangent
  vec4 t2;        // xyz: second tangent
  vec4 rA[4];     // xyz: point - A's centre of mass at the step's start; w: separation then (C0)
  vec4 rB[4];     // xyz: point - B's centre of mass; w: the approach speed for restitution
  vec4 massN;     // per point: effective masses (bodies' masses split among their contacts)
  vec4 massT1;
  vec4 massT2;
  vec4 lambdaN;   // per point: accumulated impulses
  vec4 lambdaT1;
  vec4 lambdaT2;
  vec4 maxLambdaN;  // per point: the largest normal impulse of the step (restitution)
  // Patch friction (instead of a friction pair per point): the tangent pair acts at the
  // points' centroid and a twist row turns about the normal. Its masses and impulses use
  // the first slots of the per-point ones: massT1[0], massT2[0] and lambdaT1[0], lambdaT2[0]
  // for the tangents, massT1[1] and lambdaT1[1] for the twist.
  vec4 patchRA;   // xyz: centroid - A's centre of mass; w: twist arm (mean point distance)
  vec4 patchRB;   // xyz: centroid - B's centre of mass; w: 1 with patch friction, else 0
  vec4 pushLambda;  // per point: the split push-out's accumulated impulse this step
};

// One contact's velocity changes of its two bodies in a Jacobi pass, gathered per body
// through the body's reference list (apply_deltas.comp).
struct GpuDelta {
  vec4 dvA;
  vec4 dwA;
  vec4 dvB;
  vec4 dwB;
};

// Push constants of the contact solver's passes.
struct GpuSolveConstants {
  float h;              // s, substep
  float invH;
  float biasRate;       // soft contact (Catto 2011) or Baumgarte: bias per metre of error
  float massScale;
  float impulseScale;
  float linearSlop;     // m, Baumgarte only
  float maxPushout;     // m/s
  float restitutionThreshold;  // m/s
  uint useBias;         // 0: the relax pass
  uint soft;            // soft contacts (no slop)
  uint bodyCount;
  uint refCount;        // length of the body-reference sort (a power of two)
  uint warmStart;       // start from last step's impulses
  uint jacobi;          // the Jacobi scheme (masses split among contacts), else colored Gauss-Seidel
  uint patchFriction;   // a manifold's friction at its centroid plus a twist row
  uint jointCount;      // constraint ids: joints 0..jointCount-1, then contact i as jointCount + i
  uint color;           // colored Gauss-Seidel: the color this pass solves
  uint colorLimit;      // colors dispatched; later ones go to the serial overflow
  uint mode;            // PHYS_GPU_PASS_* (joint_ldl.comp: PHYS_GPU_LDL_*)
  uint ldlIslands;      // joint islands of the joints' direct solve (0: joints iterative; else
                        // the passes leave the joints' equality rows to joint_ldl.comp)
  float positionBaumgarte;      // the position pass: fraction of the error removed per pass
  float maxPositionCorrection;  // m per pass and row
  uint refresh;                 // prepare_joints: keep the rows' impulses (a later substep)
  uint splitPushout;            // split push-out asked for: penetration beyond
                                // PHYS_GPU_SPLIT_DEPTH by pseudo velocities, in the steps
                                // whose deepest contact is deeper than that
  float jointBiasRate;          // joints' equality rows: soft (Catto 2011) or Baumgarte
  float jointMassScale;
  float jointImpulseScale;
  uint groupPasses;             // a small world (GpuWorld's kSmallConstraints): one workgroup
                                // runs this many passes (colors, rounds) in one dispatch, a
                                // barrier between them; 0: a dispatch per color or round
};

// GpuJoint.type, as phys::JointType; GpuJoint.flags.
#define PHYS_GPU_JOINT_BALL 0u
#define PHYS_GPU_JOINT_HINGE 1u
#define PHYS_GPU_JOINT_FIXED 2u
#define PHYS_GPU_JOINT_DISTANCE 3u
#define PHYS_GPU_JOINT_PRISMATIC 4u
#define PHYS_GPU_JOINT_LIMIT 1u
#define PHYS_GPU_JOINT_MOTOR 2u
#define PHYS_GPU_JOINT_MAX_ROWS 8u
// GpuJointRow kinds, as phys::RowKind.
#define PHYS_GPU_ROW_EQUALITY 2u
#define PHYS_GPU_ROW_LIMIT 3u
#define PHYS_GPU_ROW_MOTOR 4u
#define PHYS_GPU_ROW_SPRING 5u

// A joint as the device needs it, uploaded with the world's structure (world_gpu.cpp fills
// it from JointRec, phys/defs/joint_def.h's JointDef).
struct GpuJoint {
    int bodyA;      // GpuWorld body index; -1: the world or a static body (then anchorA is the
                  // world anchor and qA its orientation)
  int bodyB;      // likewise (-1: a static body; anchorB and qB in the world)
  uint type;      // PHYS_GPU_JOINT_*
  uint flags;     // PHYS_GPU_JOINT_LIMIT | _MOTOR
  vec4 anchorA;   // xyz: A's anchor from A's centre of mass, A's body axes; w: rest length (distance)
  vec4 anchorB;   // xyz: likewise for B; w: lower limit
  vec4 axisA;     // xyz: unit axis in A's body axes; w: upper limit
  vec4 axisB;     // xyz: unit axis in B's body axes; w: motor speed
  vec4 relRot0;   // conj(qA) qB at creation
  vec4 refA;      // xyz: hinge reference in A's axes; w: max motor force
  vec4 refB;      // xyz: hinge reference in B's axes; w: spring hertz (distance)
    vec4 qA;        // A's orientation when A is static
  vec4 spring;    // x: spring damping ratio; y: 1 if the distance is rigid
  vec4 qB;        // B's orientation when B is static
};

// One row of a joint for the current substep (the CPU's Row: Jacobian, error, impulse).
struct GpuJointRow {
  vec4 linA;  // xyz; w: C0 (the error minus the Jacobian times the bodies' deltas)
  vec4 angA;  // xyz; w: lambda, the accumulated impulse
  vec4 linB;  // xyz; w: effective mass
  vec4 angB;  // xyz; w: unused
  uvec4 info;  // x: kind (PHYS_GPU_ROW_*); y: rows in this row's block (1: none, 2-3: solved
               // together, on the block's first row); z: motor target / spring hertz bits;
               // w: motor max impulse / spring damping ratio bits
};

// A joint's rows (PHYS_GPU_JOINT_MAX_ROWS slots) and its blocks' inverse K matrices.
struct GpuJointRows {
  GpuJointRow rows[PHYS_GPU_JOINT_MAX_ROWS];
  vec4 invK[6];   // rows of K^-1 for the blocks starting at row 0 and row 3 (3 vec4 each)
  uint count;     // rows
  uint pad0;
  uint pad1;
  uint pad2;
};

// What a step leaves of each joint for the host: its impulses (next step's warm start on
// either backend, snapshots) and its reaction on B.
struct GpuJointOut {
  vec4 impulses[2];   // the rows' impulses, rows 0-3 and 4-7
  vec4 force;         // xyz: reaction force on B (N); w: rows
  vec4 torque;        // xyz: reaction torque on B (N m), pure rotation rows only
};

// The joints' direct solve (SolverSettings::equalitySolve = direct_ldl; Roblox's LDL hybrid):
// the equality rows of the joints, island by island (joints joined through dynamic bodies),
// in a fill-reducing order; A = J M^-1 J^T factored as L D L^T with L's pattern fixed by the
// plan (joint_ldl.h builds it on the host, joint_ldl.comp factors and solves). Row numbers
// are global: an island's rows are one contiguous range.
struct GpuLdlRow {
  uint joint;         // the joint whose row this is
  uint row;           // the row's index among the joint's rows (an equality row)
  uint patternBegin;  // row k of L: its entries L(k, i), i < k, are
  uint patternEnd;    //   pattern[patternBegin, patternEnd) as (i, index in L), i ascending
  uint columnBegin;   // column k of L: its entries L(i, k), i > k, are
  uint columnEnd;     //   values[columnBegin, columnEnd) with i = columnRows[] alike
  uint pad0;
  uint pad1;
};
// An island, solved by one workgroup (joint_ldl.comp). Its rows are ordered by level of the
// elimination tree (a row's level is one more than its highest child's, leaves at 0), so a
// level is a contiguous range of rows whose columns of L depend only on lower levels: the
// workgroup factors and solves a level's rows side by side, level after level.
struct GpuLdlIsland {
  uint firstRow;    // its rows: [firstRow, firstRow + rows)
  uint rows;
  uint firstLevel;  // its levels: levels[firstLevel, firstLevel + levels), uvec2(row begin, end)
  uint levels;
  uint firstBody;   // its dynamic bodies: bodies[firstBody, firstBody + bodies), each a
  uint bodies;      //   uvec4(body, begin, end, 0) of its rows in bodyRows[], ascending
  uint pad0;
  uint pad1;
};
// GpuSolveConstants.mode of joint_ldl.comp.
#define PHYS_GPU_LDL_FACTOR 0u  // assemble A from the rows now and factor it
#define PHYS_GPU_LDL_SOLVE 1u   // solve every equality row at once (useBias: with the error)
#define PHYS_GPU_LDL_PUSH 2u    // the same on the split push-out's pseudo velocities (no bias)

// GpuSolveConstants.mode of the colored Gauss-Seidel pass.
#define PHYS_GPU_PASS_WARM_START 0u
#define PHYS_GPU_PASS_SOLVE 1u
#define PHYS_GPU_PASS_RESTITUTION 2u
#define PHYS_GPU_PASS_POSITION 3u  // nonlinear Gauss-Seidel position pass
#define PHYS_GPU_PASS_PUSH_WARM 4u  // split push-out: the last substep's push impulses again
#define PHYS_GPU_PASS_PUSHOUT 5u    // split push-out: one pass on the pseudo velocities
// Split push-out (SolverSettings::kSplitDepth): the contacts' own bias corrects penetration
// up to this depth (m), the pseudo velocities the rest.
#define PHYS_GPU_SPLIT_DEPTH 0.01
// A one-point manifold's twist arm: a Hertz patch pressed this deep (SolverSettings::
// kPointPatchDepth, m).
#define PHYS_GPU_POINT_PATCH_DEPTH 0.005
// Graph coloring: a contact not colored yet, and one with nothing to solve.
#define PHYS_GPU_UNCOLORED 0xFFFFFFFFu
#define PHYS_GPU_NO_COLOR 0xFFFFFFFEu
#define PHYS_GPU_MAX_COLORS 64u
// Packed convex hulls (hull_pack.h, collide_hull.glsl): the words of a record's header, and
// the most vertices one face may have (the narrow phase clips faces in fixed buffers).
#define PHYS_GPU_HULL_HEADER_WORDS 12u
#define PHYS_GPU_HULL_MAX_FACE_VERTICES 32

// Push constants of the sort and scan passes (bitonic_sort.comp, scan_*.comp).
struct GpuSortConstants {
  uint n;  // values (the sort: a power of two)
  uint j;  // the sort's compare distance
  uint k;  // the sort's sequence length
  uint pad;
};

#ifdef __cplusplus
}  // namespace phys::gpu
#endif
#endif
