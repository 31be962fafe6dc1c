// The viewer in a real browser (ctest physview_browser; docs/VIEWER.md "The test"): a physd
// of its own on the default scene, physview on a free port, Debian's chromium headless driven
// by playwright-core. Checks that the page loads with no console error, draws the default
// world (window.physview: the bodies and the tick it drew), that a click drops a body that
// `physctl list` counts, that Pause stops the tick as physctl sees it and Step advances it by
// one, and writes a screenshot.
//
//   node viewer_test.mjs --physd BIN --physview BIN --physctl BIN --chromium BIN
//                        --node-modules DIR --source DIR --screenshot PNG [--headed]
import assert from 'node:assert/strict';
import { CHROMIUM_ARGS, Daemons, loadPlaywright, parseArgs, sleep } from './lib.mjs';

const opts = parseArgs(process.argv.slice(2), {
  physd: '', physview: '', physctl: '', chromium: '/usr/bin/chromium', nodeModules: '',
  source: '', screenshot: 'viewer.png', headed: false,
});
for (const k of ['physd', 'physview', 'physctl', 'nodeModules', 'source'])
  if (!opts[k]) throw new Error(`--${k.replace(/[A-Z]/g, (c) => `-${c.toLowerCase()}`)} is required`);

const { chromium } = loadPlaywright(opts.nodeModules);
const daemons = new Daemons(opts);
let browser = null;
const step = (what) => console.log(`[viewer_test] ${what}`);

async function main() {
  const started = await daemons.startPhysd();
  step(`physd on domain ${daemons.domain}: world default, ${started.bodies} bodies, running`);
  const url = await daemons.startPhysview();
  step(`physview at ${url}`);

  browser = await chromium.launch({
    executablePath: opts.chromium, headless: !opts.headed, args: CHROMIUM_ARGS,
  });
  const page = await browser.newPage({ viewport: { width: 1280, height: 760 } });
  const consoleErrors = [];
  page.on('console', (m) => { if (m.type() === 'error') consoleErrors.push(m.text()); });
  page.on('pageerror', (e) => consoleErrors.push(String(e)));
  await page.goto(url);

  // Draws the default world: every body of it, frame after frame.
  await page.waitForFunction(() => window.physview && window.physview.drawnFrames > 10
    && window.physview.bodies > 0 && window.physview.bodies === window.physview.total,
  null, { timeout: 30000 });
  let pv = await page.evaluate(() => ({ ...window.physview }));
  let w = await daemons.world();  // after the page's tick: physd's is as new or newer
  step(`page drew ${pv.drawnFrames} frames: ${pv.bodies} bodies at tick ${pv.tick}; physctl: ${w.bodies} bodies, tick ${w.tick}`);
  assert.equal(pv.bodies, w.bodies, 'the page draws every body of the world');
  assert.ok(pv.tick > 0 && pv.tick <= w.tick, 'the page draws ticks of the running world');
  const t0 = pv.tick;
  await page.waitForFunction((t) => window.physview.tick > t + 10, t0, { timeout: 10000 });

  await sleep(1500);  // the scene a moment after start: the picture in docs/
  await page.screenshot({ path: opts.screenshot });
  step(`screenshot ${opts.screenshot}`);

  // A click in the middle of the view drops a box that physd counts.
  const before = w.bodies;
  const vp = page.viewportSize();
  await page.check('#spawn-box');
  await page.mouse.click(vp.width / 2, vp.height / 2 + 60);
  await page.waitForFunction(() => window.physview.lastAck && window.physview.lastAck.op === 'spawn',
    null, { timeout: 10000 });
  await page.waitForFunction((n) => window.physview.bodies === n, before + 1, { timeout: 10000 });
  w = await daemons.world();
  pv = await page.evaluate(() => ({ ...window.physview }));
  step(`click dropped body ${pv.lastAck.id}: physctl ${w.bodies} bodies, page ${pv.bodies}`);
  assert.equal(w.bodies, before + 1, 'physctl list counts the dropped body');

  // Pause stops the tick as physctl sees it.
  await page.click('#pause');
  await page.waitForFunction(() => window.physview.lastAck && window.physview.lastAck.op === 'pause',
    null, { timeout: 10000 });
  const p1 = await daemons.world();
  await sleep(800);
  const p2 = await daemons.world();
  step(`paused: physctl ${p1.state} at tick ${p1.tick}, then ${p2.tick}`);
  assert.equal(p1.state, 'paused');
  assert.equal(p2.tick, p1.tick, 'a paused world does not tick');

  // Step advances it by one, and the page draws that tick.
  await page.click('#step');
  await page.waitForFunction(() => window.physview.lastAck && window.physview.lastAck.op === 'step',
    null, { timeout: 10000 });
  const s = await daemons.world();
  step(`step: physctl tick ${s.tick}`);
  assert.equal(s.tick, p1.tick + 1, 'Step takes one step');
  await page.waitForFunction((t) => window.physview.tick === t, s.tick, { timeout: 10000 });

  // Run again.
  await page.click('#run');
  await page.waitForFunction(() => window.physview.lastAck && window.physview.lastAck.op === 'run',
    null, { timeout: 10000 });
  await sleep(300);
  const r = await daemons.world();
  assert.equal(r.state, 'running');
  assert.ok(r.tick > s.tick, 'Run ticks again');

  pv = await page.evaluate(() => ({ ...window.physview }));
  step(`page: ${pv.drawnFrames} frames drawn, ${pv.framesReceived} received, errors ${JSON.stringify(pv.errors)}`);
  assert.deepEqual(pv.errors, [], 'the bridge reported no error');
  assert.deepEqual(consoleErrors, [], 'no console error');
  step('passed');
}

let failed = false;
try {
  await main();
} catch (e) {
  failed = true;
  console.error(`[viewer_test] FAILED: ${e.stack || e}`);
  for (const p of daemons.procs) console.error(`--- ${p.name} output ---\n${p.output}`);
} finally {
  if (browser) await browser.close().catch(() => {});
  await daemons.stop();
}
process.exit(failed ? 1 : 0);
