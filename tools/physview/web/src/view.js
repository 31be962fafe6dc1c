// The 3D view: three.js, z up. Boxes, spheres and capsules (a cylinder and two spheres) are
// instances of one InstancedMesh per kind (unit geometry scaled per instance), so 10,000
// bodies are a few draw calls; hulls and planes are meshes of their own (a world has few).
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { BOX, CAPSULE, DYNAMIC, FRAME_BODY_WORDS, HULL, KINEMATIC, PLANE, SPHERE, STATIC } from './protocol.js';

const POOL_BOX = 0;
const POOL_SPHERE = 1;
const POOL_CYLINDER = 2;

const PALETTE = [0x5b8def, 0xef8a5b, 0x5bc98a, 0xd9c35b, 0xb07cd9, 0x5bc4d9, 0xe06b8f, 0x9acd5b];
const STATIC_COLOR = 0x8a9099;
const KINEMATIC_COLOR = 0xe0a040;

/// A unit icosahedron shaded as a sphere: 20 triangles, each vertex's normal its position
/// (three.js gives detail 0 flat normals).
function smoothIcosahedron() {
  const g = new THREE.IcosahedronGeometry(1, 0);
  g.setAttribute('normal', g.getAttribute('position').clone());
  return g;
}

/// Levels of detail of spheres (capsules' caps too) and capsules' cylinders, coarsest first.
const LEVELS = [
  { triangles: 20, sphere: smoothIcosahedron, segments: 6 },
  { triangles: 64, sphere: () => new THREE.SphereGeometry(1, 8, 5), segments: 8 },
  { triangles: 168, sphere: () => new THREE.SphereGeometry(1, 12, 8), segments: 12 },
  { triangles: 720, sphere: () => new THREE.SphereGeometry(1, 24, 16), segments: 24 },
];
/// A software rasterizer's frame budget for round shapes (see View.setDetail).
const SOFTWARE_ROUND_TRIANGLES = 100000;

/// One InstancedMesh that grows (doubling) as instances are added.
class Pool {
  constructor(scene, geometry, material) {
    this.scene = scene;
    this.geometry = geometry;
    this.material = material;
    this.mesh = null;
    this.capacity = 0;
    this.count = 0;
  }
  reserve(n) {
    if (n <= this.capacity) return;
    const capacity = Math.max(n, this.capacity * 2, 256);
    const mesh = new THREE.InstancedMesh(this.geometry, this.material, capacity);
    mesh.instanceMatrix.setUsage(THREE.DynamicDrawUsage);
    mesh.instanceColor = new THREE.InstancedBufferAttribute(new Float32Array(capacity * 3), 3);
    mesh.frustumCulled = false;  // the instances move: no stale bounding sphere
    mesh.count = 0;
    if (this.mesh) {
      this.scene.remove(this.mesh);
      this.mesh.dispose();
    }
    this.scene.add(mesh);
    this.mesh = mesh;
    this.capacity = capacity;
  }
}

// Quaternion product a * b and rotation of v by q, on plain arrays.
function qmul(a, b) {
  const [ax, ay, az, aw] = a;
  const [bx, by, bz, bw] = b;
  return [aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
    aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz];
}
function qrot(q, v) {
  const [x, y, z, w] = q;
  const tx = 2 * (y * v[2] - z * v[1]);
  const ty = 2 * (z * v[0] - x * v[2]);
  const tz = 2 * (x * v[1] - y * v[0]);
  return [v[0] + w * tx + (y * tz - z * ty), v[1] + w * ty + (z * tx - x * tz), v[2] + w * tz + (x * ty - y * tx)];
}

/// Writes the matrix of (body pose) * (local pose) * scale into te at o (column-major).
function compose(te, o, px, py, pz, qx, qy, qz, qw, e) {
  let x = qx, y = qy, z = qz, w = qw;
  if (!e.identity) {
    const [lx, ly, lz, lw] = e.lq;
    x = qw * lx + qx * lw + qy * lz - qz * ly;
    y = qw * ly - qx * lz + qy * lw + qz * lx;
    z = qw * lz + qx * ly - qy * lx + qz * lw;
    w = qw * lw - qx * lx - qy * ly - qz * lz;
    const vx = e.lp[0], vy = e.lp[1], vz = e.lp[2];
    const tx = 2 * (qy * vz - qz * vy);
    const ty = 2 * (qz * vx - qx * vz);
    const tz = 2 * (qx * vy - qy * vx);
    px += vx + qw * tx + (qy * tz - qz * ty);
    py += vy + qw * ty + (qz * tx - qx * tz);
    pz += vz + qw * tz + (qx * ty - qy * tx);
  }
  const sx = e.sx, sy = e.sy, sz = e.sz;
  const x2 = x + x, y2 = y + y, z2 = z + z;
  const xx = x * x2, xy = x * y2, xz = x * z2, yy = y * y2, yz = y * z2, zz = z * z2;
  const wx = w * x2, wy = w * y2, wz = w * z2;
  te[o] = (1 - (yy + zz)) * sx; te[o + 1] = (xy + wz) * sx; te[o + 2] = (xz - wy) * sx; te[o + 3] = 0;
  te[o + 4] = (xy - wz) * sy; te[o + 5] = (1 - (xx + zz)) * sy; te[o + 6] = (yz + wx) * sy; te[o + 7] = 0;
  te[o + 8] = (xz + wy) * sz; te[o + 9] = (yz - wx) * sz; te[o + 10] = (1 - (xx + yy)) * sz; te[o + 11] = 0;
  te[o + 12] = px; te[o + 13] = py; te[o + 14] = pz; te[o + 15] = 1;
}

function entry(lp, lq, sx, sy, sz) {
  const identity = lp[0] === 0 && lp[1] === 0 && lp[2] === 0 && lq[0] === 0 && lq[1] === 0 && lq[2] === 0;
  return { lp, lq, sx, sy, sz, identity, pool: -1, inst: -1, mesh: null };
}

/// WebGL's renderer, as the driver names it ('' where it does not say).
export function rendererName() {
  try {
    const gl = document.createElement('canvas').getContext('webgl2');
    const info = gl && gl.getExtension('WEBGL_debug_renderer_info');
    const name = info ? String(gl.getParameter(info.UNMASKED_RENDERER_WEBGL)) : '';
    const lose = gl && gl.getExtension('WEBGL_lose_context');
    if (lose) lose.loseContext();
    return name;
  } catch {
    return '';
  }
}

/// Whether WebGL runs on a software rasterizer (SwiftShader, llvmpipe): headless browsers,
/// machines without a GPU. Antialiasing is then left off (it costs most of the frame there).
export function softwareRenderer(name = rendererName()) {
  return /swiftshader|llvmpipe|softpipe|software/i.test(name);
}

export class View {
  /// options: antialias (default: unless the renderer is software), pixelRatio (default: the
  /// device's, at most 2).
  constructor(container, options = {}) {
    this.container = container;
    this.rendererName = rendererName();
    this.software = softwareRenderer(this.rendererName);
    const antialias = options.antialias ?? !this.software;
    const renderer = new THREE.WebGLRenderer({ antialias, powerPreference: 'high-performance' });
    renderer.setPixelRatio(options.pixelRatio ?? Math.min(window.devicePixelRatio || 1, 2));
    renderer.setSize(container.clientWidth, container.clientHeight);
    container.appendChild(renderer.domElement);
    this.renderer = renderer;

    const scene = new THREE.Scene();
    scene.background = new THREE.Color(0x1d2127);
    scene.fog = new THREE.Fog(0x1d2127, 60, 300);  // fit() scales it to the scene
    this.scene = scene;
    const camera = new THREE.PerspectiveCamera(50, container.clientWidth / container.clientHeight, 0.05, 4000);
    camera.up.set(0, 0, 1);
    camera.position.set(18, -24, 14);
    this.camera = camera;
    const controls = new OrbitControls(camera, renderer.domElement);
    controls.target.set(0, 0, 2);
    controls.update();
    this.controls = controls;
    const hemi = new THREE.HemisphereLight(0xe8eeff, 0x403a34, 1.8);
    hemi.position.set(0, 0, 1);
    scene.add(hemi);
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(12, -18, 30);
    scene.add(sun);

    const material = new THREE.MeshLambertMaterial({ color: 0xffffff });
    this.pools = [
      new Pool(scene, new THREE.BoxGeometry(2, 2, 2), material),
      new Pool(scene, null, material),
      new Pool(scene, null, material),
    ];
    this.detail = -1;
    this.hullMaterial = new THREE.MeshLambertMaterial({ color: 0xffffff, flatShading: true });
    this.planeMaterial = new THREE.MeshLambertMaterial({
      color: 0x4a525c, side: THREE.DoubleSide,
      polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1,
    });
    this.meshes = [];          // hull and plane objects of the current layout
    this.byIndex = [];         // description by body id index (generation checked)
    this.layoutIdx = new Uint32Array(0);
    this.layoutGen = new Uint32Array(0);
    this.layoutDesc = [];
    this.layoutCount = -1;
    this.layoutDirty = true;
    this.drawnBodies = 0;
    this.fitPending = true;
    this.tmpColor = new THREE.Color();
  }

  resize() {
    const w = this.container.clientWidth;
    const h = this.container.clientHeight;
    this.renderer.setSize(w, h);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
  }

  /// A shapes message: descriptions of bodies the page has not seen (reset: of a new world).
  addShapes(msg) {
    if (msg.reset) this.clear();
    for (const b of msg.bodies) {
      const entries = [];
      for (const s of b.shapes) this.entriesOf(s, entries);
      this.byIndex[b.index] = { gen: b.gen, motion: b.motion, shapes: b.shapes, entries, color: this.colorOf(b) };
    }
    this.layoutDirty = true;
  }

  /// Drops every description and every drawn body (a shapes reset: another world).
  clear() {
    for (const m of this.meshes) {
      this.scene.remove(m);
      m.traverse((o) => {  // hull and plane meshes are the old world's alone
        if (o.geometry) o.geometry.dispose();
        if (o.material && o.material !== this.planeMaterial) o.material.dispose();
      });
    }
    this.meshes = [];
    for (const p of this.pools) {
      p.count = 0;
      if (p.mesh) p.mesh.count = 0;
    }
    this.byIndex = [];
    this.layoutDesc = [];
    this.layoutCount = -1;
    this.layoutDirty = true;
    this.drawnBodies = 0;
    this.fitPending = true;
  }

  colorOf(b) {
    if (b.motion === STATIC) return STATIC_COLOR;
    if (b.motion === KINEMATIC) return KINEMATIC_COLOR;
    return PALETTE[(Math.imul(b.index, 2654435761) >>> 0) % PALETTE.length];
  }

  /// The instances (or meshes) that draw one shape, each with its pose in the body frame.
  entriesOf(s, out) {
    const [r, b, c, d] = s.dims;
    switch (s.kind) {
      case BOX: {
        const e = entry(s.lp, s.lq, r, b, c);
        e.pool = POOL_BOX;
        out.push(e);
        break;
      }
      case SPHERE: {
        const e = entry(s.lp, s.lq, r, r, r);
        e.pool = POOL_SPHERE;
        out.push(e);
        break;
      }
      case CAPSULE: {  // radius r, half height b along local z
        const cyl = entry(s.lp, s.lq, r, r, Math.max(2 * b, 1e-4));
        cyl.pool = POOL_CYLINDER;
        out.push(cyl);
        for (const sign of [-1, 1]) {
          const off = qrot(s.lq, [0, 0, sign * b]);
          const cap = entry([s.lp[0] + off[0], s.lp[1] + off[1], s.lp[2] + off[2]], s.lq, r, r, r);
          cap.pool = POOL_SPHERE;
          out.push(cap);
        }
        break;
      }
      case PLANE: {  // {x : dot(n, x) = d} in the body frame: z of the drawn plane along n
        const n = new THREE.Vector3(r, b, c).normalize();
        const q = new THREE.Quaternion().setFromUnitVectors(new THREE.Vector3(0, 0, 1), n);
        const lq = qmul(s.lq, [q.x, q.y, q.z, q.w]);
        const off = qrot(s.lq, [n.x * d, n.y * d, n.z * d]);
        const e = entry([s.lp[0] + off[0], s.lp[1] + off[1], s.lp[2] + off[2]], lq, 1, 1, 1);
        e.plane = true;
        out.push(e);
        break;
      }
      case HULL: {
        if (!s.hull) break;
        const e = entry(s.lp, s.lq, 1, 1, 1);
        e.hull = s.hull;
        out.push(e);
        break;
      }
      default:
        break;
    }
  }

  /// Instances for the bodies of this frame that have descriptions, in frame order.
  relayout(frame) {
    const { u, count } = frame;
    for (const m of this.meshes) this.scene.remove(m);
    this.meshes = [];
    const need = [0, 0, 0];
    const desc = new Array(count);
    this.layoutIdx = new Uint32Array(count);
    this.layoutGen = new Uint32Array(count);
    let drawn = 0;
    for (let i = 0, o = 0; i < count; ++i, o += FRAME_BODY_WORDS) {
      const index = u[o];
      const gen = u[o + 1];
      this.layoutIdx[i] = index;
      this.layoutGen[i] = gen;
      const d = this.byIndex[index];
      if (!d || d.gen !== gen) continue;
      desc[i] = d;
      ++drawn;
      for (const e of d.entries) if (e.pool >= 0) ++need[e.pool];
    }
    this.setDetail(need[POOL_SPHERE] + need[POOL_CYLINDER]);
    this.pools.forEach((p, k) => { p.reserve(need[k]); p.count = 0; });
    const color = this.tmpColor;
    for (let i = 0; i < count; ++i) {
      const d = desc[i];
      if (!d) continue;
      color.setHex(d.color);
      for (const e of d.entries) {
        if (e.pool >= 0) {
          const p = this.pools[e.pool];
          e.inst = p.count++;
          p.mesh.setColorAt(e.inst, color);
        } else {
          if (!e.mesh) e.mesh = e.plane ? this.planeObject() : this.hullObject(e.hull, d.color);
          e.mesh.matrixAutoUpdate = false;
          this.scene.add(e.mesh);
          this.meshes.push(e.mesh);
        }
      }
    }
    for (const p of this.pools) {
      if (!p.mesh) continue;
      p.mesh.count = p.count;
      if (p.mesh.instanceColor) p.mesh.instanceColor.needsUpdate = true;
    }
    this.layoutDesc = desc;
    this.layoutCount = count;
    this.layoutDirty = false;
    this.drawnBodies = drawn;
  }

  /// Round shapes with fewer triangles as they get many. On a GPU by the instance count; on
  /// a software rasterizer (headless chromium, a machine without a GPU), which is bound by
  /// triangles (about 6 million a second with llvmpipe on two cores, a quarter of that with
  /// SwiftShader; docs/VIEWER.md "Performance"), the finest level whose round shapes stay
  /// within SOFTWARE_ROUND_TRIANGLES a frame, down to a 20-triangle sphere.
  setDetail(roundInstances) {
    let detail = 0;
    if (this.software) {
      for (let d = LEVELS.length - 1; d > 0 && !detail; --d)
        if (roundInstances * LEVELS[d].triangles <= SOFTWARE_ROUND_TRIANGLES) detail = d;
    } else {
      detail = roundInstances < 2000 ? 3 : roundInstances < 8000 ? 2 : 1;
    }
    if (detail === this.detail) return;
    this.detail = detail;
    const level = LEVELS[detail];
    const sphere = level.sphere();
    const cylinder = new THREE.CylinderGeometry(1, 1, 1, level.segments, 1, true).rotateX(Math.PI / 2);
    for (const [pool, g] of [[this.pools[POOL_SPHERE], sphere], [this.pools[POOL_CYLINDER], cylinder]]) {
      if (pool.geometry) pool.geometry.dispose();
      pool.geometry = g;
      if (pool.mesh) pool.mesh.geometry = g;
    }
  }

  planeObject() {
    const group = new THREE.Group();
    group.add(new THREE.Mesh(new THREE.PlaneGeometry(20000, 20000), this.planeMaterial));
    const grid = new THREE.GridHelper(200, 200, 0x6b7480, 0x58616c);  // 1 m cells
    grid.rotateX(Math.PI / 2);  // the helper lies in x-z; the plane's normal is z
    grid.position.z = 0.001;
    group.add(grid);
    return group;
  }

  hullObject(hull, color) {
    if (!hull.geometry) {
      const g = new THREE.BufferGeometry();
      g.setAttribute('position', new THREE.BufferAttribute(hull.vertices, 3));
      g.setIndex(new THREE.BufferAttribute(hull.indices, 1));
      const flat = g.toNonIndexed();
      flat.computeVertexNormals();
      hull.geometry = flat;
    }
    const m = new THREE.Mesh(hull.geometry, this.hullMaterial.clone());
    m.material.color.setHex(color);
    return m;
  }

  /// A frame onto the instances; false when nothing of it could be drawn yet.
  apply(frame) {
    const { u, f, count } = frame;
    let same = !this.layoutDirty && count === this.layoutCount;
    for (let i = 0, o = 0; same && i < count; ++i, o += FRAME_BODY_WORDS)
      same = u[o] === this.layoutIdx[i] && u[o + 1] === this.layoutGen[i];
    if (!same) this.relayout(frame);
    const arrays = this.pools.map((p) => (p.mesh ? p.mesh.instanceMatrix.array : null));
    const desc = this.layoutDesc;
    for (let i = 0, o = 0; i < count; ++i, o += FRAME_BODY_WORDS) {
      const d = desc[i];
      if (!d) continue;
      const px = f[o + 2], py = f[o + 3], pz = f[o + 4];
      const qx = f[o + 5], qy = f[o + 6], qz = f[o + 7], qw = f[o + 8];
      const entries = d.entries;
      for (let k = 0; k < entries.length; ++k) {
        const e = entries[k];
        if (e.pool >= 0) {
          compose(arrays[e.pool], e.inst * 16, px, py, pz, qx, qy, qz, qw, e);
        } else if (e.mesh) {
          compose(e.mesh.matrix.elements, 0, px, py, pz, qx, qy, qz, qw, e);
          e.mesh.matrixWorldNeedsUpdate = true;
        }
      }
    }
    for (const p of this.pools) if (p.mesh && p.count) p.mesh.instanceMatrix.needsUpdate = true;
    if (this.fitPending && this.drawnBodies > 0) {
      this.fit(frame);
      this.fitPending = false;
    }
    return this.drawnBodies > 0;
  }

  /// Points the camera at the bodies (planes left out).
  fit(frame) {
    const { f, count } = frame;
    const box = new THREE.Box3();
    const p = new THREE.Vector3();
    for (let i = 0, o = 0; i < count; ++i, o += FRAME_BODY_WORDS) {
      const d = this.layoutDesc[i];
      if (!d || d.entries.some((e) => e.plane)) continue;
      p.set(f[o + 2], f[o + 3], f[o + 4]);
      if (Number.isFinite(p.x) && Number.isFinite(p.y) && Number.isFinite(p.z)) box.expandByPoint(p);
    }
    if (box.isEmpty()) return;
    const center = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3()).length();
    const distance = Math.max(8, size * 1.1);
    const dir = new THREE.Vector3(0.55, -0.75, 0.42).normalize();
    this.controls.target.copy(center);
    this.camera.position.copy(center).addScaledVector(dir, distance);
    this.camera.far = Math.max(4000, distance * 20);
    this.scene.fog.near = distance * 1.5;  // the ground fades out behind the bodies
    this.scene.fog.far = distance * 5;
    this.camera.updateProjectionMatrix();
    this.controls.update();
  }

  /// Where a click at client (x, y) drops a body: a bit in front of the first surface the ray
  /// hits (back along the ray), else above the z = 0 plane; null when the ray misses both.
  pick(clientX, clientY) {
    const rect = this.renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(((clientX - rect.left) / rect.width) * 2 - 1,
      -((clientY - rect.top) / rect.height) * 2 + 1);
    const ray = new THREE.Raycaster();
    ray.setFromCamera(ndc, this.camera);
    const targets = [];
    for (const p of this.pools) {
      if (!p.mesh || !p.count) continue;
      p.mesh.boundingSphere = null;  // recomputed from the instances as they are now
      p.mesh.boundingBox = null;
      targets.push(p.mesh);
    }
    for (const m of this.meshes) targets.push(m);
    this.scene.updateMatrixWorld();
    const hits = ray.intersectObjects(targets, true);
    const dir = ray.ray.direction;
    if (hits.length) {
      const h = hits[0].point;
      return [h.x - dir.x * 1.0, h.y - dir.y * 1.0, h.z - dir.z * 1.0 + 0.3];
    }
    if (Math.abs(dir.z) < 1e-6) return null;
    const t = -ray.ray.origin.z / dir.z;
    if (t <= 0) return null;
    const o = ray.ray.origin;
    return [o.x + dir.x * t, o.y + dir.y * t, 1.5];
  }

  render() {
    this.renderer.render(this.scene, this.camera);
  }
}
