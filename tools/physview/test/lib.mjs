// Helpers of the viewer test and benchmark: a physd and a physview of their own (a DDS domain
// and a Cyclone discovery tag of this process, as tests/client/physd_process.h does), physctl
// runs, playwright-core from the build folder's node_modules.
import { execFile, spawn } from 'node:child_process';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { createRequire } from 'node:module';
import { tmpdir } from 'node:os';
import { join, resolve } from 'node:path';

export function parseArgs(argv, defaults) {
  const out = { ...defaults };
  for (let i = 0; i < argv.length; ++i) {
    const a = argv[i];
    if (!a.startsWith('--')) throw new Error(`unexpected argument ${a}`);
    const key = a.slice(2).replace(/-([a-z])/g, (_, c) => c.toUpperCase());
    if (typeof out[key] === 'boolean') out[key] = true;
    else out[key] = argv[++i];
  }
  return out;
}

export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

export function loadPlaywright(nodeModules) {
  return createRequire(join(resolve(nodeModules), 'noop.js'))('playwright-core');
}

/// A physd on a domain of its own with one start-up world; stop() ends it and physview.
export class Daemons {
  constructor(opts) {
    this.opts = opts;
    this.dir = mkdtempSync(join(tmpdir(), 'physview_test_'));
    this.domain = 180 + (process.pid % 40);
    this.procs = [];
    const loopback = readFileSync(join(opts.source, 'configs/cyclonedds/loopback.xml'), 'utf8');
    this.xml = join(this.dir, 'cyclone.xml');
    writeFileSync(this.xml, loopback.replace('<Discovery>',
      `<Discovery><Tag>physview-test-${process.pid}</Tag>`));
    this.toml = join(this.dir, 'physd.toml');
    writeFileSync(this.toml, [
      '[server]', 'name = "physd-viewer-test"', 'log_level = "warn"', 'status_period_s = 0.2',
      '[dds]', `domain = ${this.domain}`, `config = "${this.xml}"`,
      '[paths]', `presets = "${opts.source}/configs/presets.json"`,
      `scenes = "${opts.source}/configs/scenes"`, `snapshots = "${this.dir}/snapshots"`,
      '[[worlds]]', 'name = "default"', `scene = "${opts.scene || 'default'}"`, 'run = true',
      'rate_hz = 60', '',
    ].join('\n'));
  }

  physctl(...args) {
    return new Promise((resolve, reject) => {
      execFile(this.opts.physctl, ['--domain', String(this.domain), '--config', this.xml,
        '--timeout', '5000', ...args], { timeout: 30000 }, (err, stdout, stderr) => {
        if (err) reject(new Error(`physctl ${args.join(' ')}: ${stderr || err.message}`));
        else resolve(stdout);
      });
    });
  }

  /// The world's row of `physctl list`: name, awake, bodies, joints, contacts, tick, state.
  async world(name = 'default') {
    const out = await this.physctl('list');
    for (const line of out.split('\n').slice(1)) {
      const t = line.trim().split(/\s+/);
      if (t.length < 14 || t[1] !== name) continue;
      const n = t.length;  // the preset column may be empty: count the rest from the end
      return {
        id: Number(t[0]), name: t[1], awake: Number(t[n - 12]), bodies: Number(t[n - 11]),
        joints: Number(t[n - 10]), contacts: Number(t[n - 9]), tick: Number(t[n - 7]),
        state: t[n - 5],
      };
    }
    throw new Error(`physctl list has no world ${name}:\n${out}`);
  }

  start(binary, args, name) {
    const p = spawn(binary, args, { stdio: ['ignore', 'pipe', 'pipe'] });
    p.name = name;
    p.output = '';
    p.stdout.on('data', (d) => { p.output += d; });
    p.stderr.on('data', (d) => { p.output += d; });
    this.procs.push(p);
    return p;
  }

  async startPhysd() {
    this.physd = this.start(this.opts.physd, ['--config', this.toml], 'physd');
    const end = Date.now() + 60000;
    for (;;) {
      if (this.physd.exitCode !== null) throw new Error(`physd exited:\n${this.physd.output}`);
      try {
        const w = await this.world('default');
        if (w.state === 'running') return w;
      } catch { /* not up yet */ }
      if (Date.now() > end) throw new Error(`physd did not run its world:\n${this.physd.output}`);
      await sleep(300);
    }
  }

  /// physview on a free port; resolves with the URL it prints.
  async startPhysview(extra = []) {
    const p = this.start(this.opts.physview, ['--domain', String(this.domain), '--config', this.xml,
      '--port', '0', '--timeout', '5000', ...extra], 'physview');
    this.physview = p;
    const end = Date.now() + 30000;
    for (;;) {
      const m = /serving (http:\/\/\S+)/.exec(p.output);
      if (m) return m[1];
      if (p.exitCode !== null) throw new Error(`physview exited:\n${p.output}`);
      if (Date.now() > end) throw new Error(`physview printed no URL:\n${p.output}`);
      await sleep(100);
    }
  }

  async stop() {
    for (const p of this.procs.reverse()) {
      if (p.exitCode !== null || p.signalCode !== null) continue;
      const done = new Promise((r) => p.once('exit', r));
      p.kill('SIGTERM');
      await Promise.race([done, sleep(5000)]);
      if (p.exitCode === null && p.signalCode === null) p.kill('SIGKILL');
    }
    rmSync(this.dir, { recursive: true, force: true });
  }
}

const HEADLESS_ARGS = ['--no-sandbox', '--headless=new', '--ignore-gpu-blocklist'];
export const CHROMIUM_ARGS = [
  ...HEADLESS_ARGS,
  // WebGL without a GPU: ANGLE on SwiftShader (Chromium asks for the opt-in since 2025).
  '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
];

/// The arguments for a WebGL backend: 'swiftshader' (CHROMIUM_ARGS), or 'llvmpipe': ANGLE
/// over EGL on Mesa's llvmpipe (libgl1-mesa-dri; it rasterizes on LP_NUM_THREADS threads, and
/// is the faster of the two software rasterizers here, docs/BENCHMARKS.md "Browser viewer").
export function chromiumArgs(gl = 'swiftshader') {
  if (gl === 'swiftshader') return CHROMIUM_ARGS;
  if (gl === 'llvmpipe') {
    return [...HEADLESS_ARGS, '--use-gl=angle', '--use-angle=gl-egl'];
  }
  throw new Error(`--gl ${gl}: swiftshader or llvmpipe`);
}
