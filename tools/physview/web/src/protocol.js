// physview's binary messages (tools/physview/messages.h, docs/VIEWER.md "Messages"): 32-bit
// little-endian words read through typed-array views over the message, no copy per body.

export const FRAME = 1;
export const SHAPES = 2;
export const FRAME_HEADER_BYTES = 48;
export const FRAME_BODY_WORDS = 9;
export const SHAPE_WORDS = 12;
export const SHAPES_RESET = 1;

// Shape kinds (phys::ShapeType) and motion types (phys::BodyType).
export const SPHERE = 0;
export const BOX = 1;
export const CAPSULE = 2;
export const PLANE = 3;
export const HULL = 4;
export const STATIC = 0;
export const KINEMATIC = 1;
export const DYNAMIC = 2;

export function messageKind(buffer) {
  return buffer.byteLength >= 4 ? new Uint32Array(buffer, 0, 1)[0] : 0;
}

/// The world a frame or shapes message is of (0 when too short to say).
export function messageWorld(buffer) {
  return buffer.byteLength >= 8 ? new Uint32Array(buffer, 4, 1)[0] : 0;
}

/// A frame: its header, and u32 / f32 views of its body records (9 words a body: id index, id
/// generation, position x y z, rotation x y z w).
export function decodeFrame(buffer) {
  const dv = new DataView(buffer);
  const count = dv.getUint32(36, true);
  if (buffer.byteLength < FRAME_HEADER_BYTES + count * FRAME_BODY_WORDS * 4) throw new Error('short frame');
  return {
    world: dv.getUint32(4, true),
    tick: dv.getUint32(8, true) + dv.getUint32(12, true) * 4294967296,
    time: dv.getFloat64(16, true),
    tickMs: dv.getFloat32(24, true),
    awake: dv.getUint32(28, true),
    total: dv.getUint32(32, true),
    count,
    contacts: dv.getUint32(40, true),
    running: (dv.getUint32(44, true) & 1) !== 0,
    u: new Uint32Array(buffer, FRAME_HEADER_BYTES, count * FRAME_BODY_WORDS),
    f: new Float32Array(buffer, FRAME_HEADER_BYTES, count * FRAME_BODY_WORDS),
  };
}

/// A shapes message: { world, reset, bodies: [{ index, gen, motion, shapes: [{ kind, lp,
/// lq, dims, hull }] }] }, hulls as { vertices: Float32Array, indices: Uint32Array }.
export function decodeShapes(buffer) {
  const u = new Uint32Array(buffer);
  const f = new Float32Array(buffer);
  const world = u[1];
  const flags = u[2];
  const bodyCount = u[3];
  const hullCount = u[4];
  let i = 6;
  const hulls = [];
  for (let h = 0; h < hullCount; ++h) {
    const nv = u[i];
    const ni = u[i + 1];
    i += 2;
    const vertices = f.slice(i, i + nv * 3);
    i += nv * 3;
    const indices = u.slice(i, i + ni);
    i += ni;
    hulls.push({ vertices, indices, geometry: null });
  }
  const bodies = new Array(bodyCount);
  for (let b = 0; b < bodyCount; ++b) {
    const index = u[i];
    const gen = u[i + 1];
    const motion = u[i + 2];
    const n = u[i + 3];
    i += 4;
    const shapes = new Array(n);
    for (let s = 0; s < n; ++s) {
      const kind = u[i];
      shapes[s] = {
        kind,
        lp: [f[i + 1], f[i + 2], f[i + 3]],
        lq: [f[i + 4], f[i + 5], f[i + 6], f[i + 7]],
        dims: [f[i + 8], f[i + 9], f[i + 10], f[i + 11]],
        hull: kind === HULL ? (hulls[u[i + 8]] || null) : null,
      };
      i += SHAPE_WORDS;
    }
    bodies[b] = { index, gen, motion, shapes };
  }
  return { world, reset: (flags & SHAPES_RESET) !== 0, bodies };
}
