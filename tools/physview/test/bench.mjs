// The viewer's frame rate with many bodies (docs/VIEWER.md "Performance"): a physd of its own
// running a generated scene of N bodies at 60 Hz (boxes, spheres and capsules on a grid in
// zero gravity, each spinning, the whole grid drifting: every body moves every tick, none
// touch), physview on a free port, Debian's chromium headless. Over a measuring window it
// reports the page's requestAnimationFrame rate, the frames it applied (received from the
// bridge and drawn), and the CPU of physview and physd from /proc.
//
//   node bench.mjs --physd BIN --physview BIN --physctl BIN --chromium BIN
//                  --node-modules DIR --source DIR [--bodies 10000] [--seconds 10]
//                  [--warmup 5] [--width 1280] [--height 720] [--query aa=0] [--json FILE]
//                  [--gl swiftshader|llvmpipe]
import { readFileSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { chromiumArgs, Daemons, loadPlaywright, parseArgs, sleep } from './lib.mjs';

const opts = parseArgs(process.argv.slice(2), {
  physd: '', physview: '', physctl: '', chromium: '/usr/bin/chromium', nodeModules: '',
  source: '', bodies: '10000', seconds: '10', warmup: '5', width: '1280', height: '720',
  query: '', json: '', screenshot: '', gl: 'swiftshader',
});
const N = Number(opts.bodies);

function scene(n) {
  const side = Math.ceil(Math.sqrt(n));
  const bodies = [];
  let seed = 12345;
  const rnd = () => ((seed = (Math.imul(seed, 1103515245) + 12345) >>> 0) / 4294967296);
  const r = (x) => Math.round(x * 1000) / 1000;
  for (let i = 0; i < n; ++i) {
    const x = (i % side - side / 2) * 1.5;
    const y = (Math.floor(i / side) - side / 2) * 1.5;
    const kind = i % 3;
    const shape = kind === 0 ? { type: 'box', half_extents: [0.3, 0.2, 0.15] }
      : kind === 1 ? { type: 'sphere', radius: 0.25 } : { type: 'capsule', radius: 0.15, half_height: 0.25 };
    bodies.push({
      position: [r(x), r(y), 2],
      linear_velocity: [0, 0, 0.05],
      angular_velocity: [r(rnd() * 4 - 2), r(rnd() * 4 - 2), r(rnd() * 4 - 2)],
      shapes: [shape],
    });
  }
  return { name: `spin_${n}`, description: 'physview benchmark: spinning bodies, no contacts',
    gravity: [0, 0, 0], sleep: false, bodies };
}

function cpuTicks(pid) {  // utime + stime of a process, in clock ticks (100 a second)
  const stat = readFileSync(`/proc/${pid}/stat`, 'utf8');
  const f = stat.slice(stat.lastIndexOf(')') + 2).split(' ');
  return Number(f[11]) + Number(f[12]);
}

const { chromium } = loadPlaywright(opts.nodeModules);
const daemons = new Daemons({ ...opts, scene: `spin_${N}` });
writeFileSync(join(daemons.dir, `spin_${N}.json`), JSON.stringify(scene(N)));
// The generated scene beside the source tree's presets.
writeFileSync(daemons.toml, readFileSync(daemons.toml, 'utf8')
  .replace(`scenes = "${opts.source}/configs/scenes"`, `scenes = "${daemons.dir}"`));
let browser = null;
let failed = false;
try {
  await daemons.startPhysd();
  const url = await daemons.startPhysview();
  browser = await chromium.launch({ executablePath: opts.chromium, headless: true, args: chromiumArgs(opts.gl) });
  const page = await browser.newPage({ viewport: { width: Number(opts.width), height: Number(opts.height) } });
  const errors = [];
  page.on('console', (m) => { if (m.type() === 'error') errors.push(m.text()); });
  page.on('pageerror', (e) => errors.push(String(e)));
  await page.goto(opts.query ? `${url}?${opts.query}` : url);
  await page.waitForFunction((n) => window.physview && window.physview.bodies === n, N, { timeout: 120000 });
  await sleep(Number(opts.warmup) * 1000);
  const sample = async () => ({
    t: Date.now(),
    page: await page.evaluate(() => ({ ...window.physview, errors: undefined, worlds: undefined, lastAck: undefined })),
    physview: cpuTicks(daemons.physview.pid),
    physd: cpuTicks(daemons.physd.pid),
    world: await daemons.world(),
  });
  const a = await sample();
  await sleep(Number(opts.seconds) * 1000);
  const b = await sample();
  const s = (b.t - a.t) / 1000;
  const result = {
    bodies: N,
    seconds: s,
    viewport: `${opts.width}x${opts.height}`,
    query: opts.query,
    gl: opts.gl,
    renderer: b.page.renderer,
    software: b.page.software,
    antialias: b.page.antialias,
    rafHz: (b.page.animationFrames - a.page.animationFrames) / s,
    appliedHz: (b.page.drawnFrames - a.page.drawnFrames) / s,
    receivedHz: (b.page.framesReceived - a.page.framesReceived) / s,
    physdTickHz: (b.world.tick - a.world.tick) / s,
    physviewCpuPct: (b.physview - a.physview) / s,  // 100 ticks a second = 100 %
    physdCpuPct: (b.physd - a.physd) / s,
    // physview's CPU per frame it sent (10 ms a clock tick).
    physviewCpuMsPerFrame: ((b.physview - a.physview) * 10) / Math.max(1, b.page.framesReceived - a.page.framesReceived),
    load: readFileSync('/proc/loadavg', 'utf8').split(' ').slice(0, 3).join(' '),
    applyMsPerFrame: (b.page.applyMs - a.page.applyMs) / Math.max(1, b.page.drawnFrames - a.page.drawnFrames),
    renderMsPerFrame: (b.page.renderMs - a.page.renderMs) / Math.max(1, b.page.renders - a.page.renders),
    drawnBodies: b.page.bodies,
    consoleErrors: errors,
  };
  if (opts.screenshot) await page.screenshot({ path: opts.screenshot });
  console.log(JSON.stringify(result, null, 1));
  if (opts.json) writeFileSync(opts.json, JSON.stringify(result, null, 1));
} catch (e) {
  failed = true;
  console.error(`bench failed: ${e.stack || e}`);
  for (const p of daemons.procs) console.error(`--- ${p.name} ---\n${p.output}`);
} finally {
  if (browser) await browser.close().catch(() => {});
  await daemons.stop();
}
process.exit(failed ? 1 : 0);
