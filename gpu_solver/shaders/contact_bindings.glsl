// Bindings of the contact passes that work on local copies of two bodies and write deltas
// (contact_warm_start, contact_solve, contact_restitution).
layout(std430, binding = 0) readonly buffer Bodies { GpuSolverBody bodies[]; };
layout(std430, binding = 1) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 2) buffer Contacts { GpuContact contacts[]; };
layout(std430, binding = 3) writeonly buffer Deltas { GpuDelta deltas[]; };
layout(std430, binding = 4) readonly buffer Counters { uint counters[]; };
layout(std430, binding = 5) readonly buffer Refs { uvec4 refs[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };
