// The viewer in a real browser (ctest physview_browser; docs/VIEWER.md "The test"): a physd
// of its own on the default scene, physview on a free port, Debian's chromium headless driven
// by playwright-core. Checks that the page loads with no console error, draws the default
// world (window.physview: the bodies and the tick it drew), that a click drops a body that
// `physctl list` counts, that Pause stops the tick as physctl sees it and Step advances it by
// one, that the WebSocket refuses pages of other origins and a ninth page, and writes a
// screenshot.
//
//   node viewer_test.mjs --physd BIN --physview BIN --physctl BIN --chromium BIN
//                        --node-modules DIR --source DIR --screenshot PNG [--headed]
import assert from 'node:assert/strict';
import net from 'node:net';
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

/// fn() until it returns something truthy (returned), every 100 ms, for at most ms: the test
/// waits for what it checks, not for a fixed time (the host may be loaded).
async function until(what, fn, ms = 10000) {
  const end = Date.now() + ms;
  for (;;) {
    const v = await fn();
    if (v) return v;
    if (Date.now() > end) throw new Error(`timed out after ${ms} ms: ${what}`);
    await sleep(100);
  }
}

/// A WebSocket handshake by hand over a socket (a browser's headers, Origin among them):
/// resolves with the answer's status (0: closed with no answer) and the socket, left open.
function upgrade(port, headers) {
  return new Promise((resolve, reject) => {
    const sock = net.connect(port, '127.0.0.1');
    let data = '';
    let done = false;
    const finish = (status) => {
      if (done) return;
      done = true;
      clearTimeout(timer);
      resolve({ status, sock });
    };
    const timer = setTimeout(() => {
      sock.destroy();
      reject(new Error(`no answer to a WebSocket handshake with ${headers.join(', ')}`));
    }, 10000);
    sock.on('connect', () => sock.write([
      'GET /ws HTTP/1.1', ...headers, 'Upgrade: websocket', 'Connection: Upgrade',
      'Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==', 'Sec-WebSocket-Version: 13', '', '',
    ].join('\r\n')));
    sock.on('data', (d) => {
      data += d.toString('latin1');
      if (data.includes('\r\n\r\n')) finish(Number((/^HTTP\/1\.[01] (\d{3})/.exec(data) || [])[1] || -1));
    });
    sock.on('error', () => {});  // 'close' follows
    sock.on('close', () => finish(0));
  });
}

/// Whether sock is closed by the other end within ms.
function closedWithin(sock, ms) {
  if (sock.destroyed) return Promise.resolve(true);
  return new Promise((resolve) => {
    const timer = setTimeout(() => resolve(false), ms);
    sock.once('close', () => { clearTimeout(timer); resolve(true); });
  });
}

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

  await sleep(1500);  // not a wait for anything: the scene a moment later is the picture in docs/
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
  await sleep(800);  // not a wait for anything: the window in which a running world would tick
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
  const r = await until('physctl sees the world run and tick again after Run', async () => {
    const x = await daemons.world();
    return x.state === 'running' && x.tick > s.tick ? x : null;
  });
  step(`run: physctl ${r.state} at tick ${r.tick}`);

  // The WebSocket: only pages of physview's own origin (a browser lets any site's page open
  // ws://127.0.0.1:PORT/ws), at most eight pages at once.
  const port = Number(new URL(url).port);
  const host = `Host: 127.0.0.1:${port}`;
  const foreign = await upgrade(port, [host, 'Origin: http://evil.example']);
  foreign.sock.destroy();
  const rebound = await upgrade(port, [`Host: evil.example:${port}`, `Origin: http://evil.example:${port}`]);
  rebound.sock.destroy();
  step(`handshakes: Origin evil.example ${foreign.status}, evil.example as Host and Origin ${rebound.status}`);
  assert.equal(foreign.status, 403, 'a page of another origin gets no WebSocket');
  assert.equal(rebound.status, 403, 'a page of another host name (DNS rebinding) gets no WebSocket');
  const own = await upgrade(port, [host, `Origin: http://127.0.0.1:${port}`]);
  assert.equal(own.status, 101, 'a page of the same origin gets its WebSocket');
  // A command of more than 4 KiB closes the connection (one masked text frame, mask 0).
  const big = Buffer.alloc(5000, 0x20);
  own.sock.write(Buffer.concat([Buffer.from([0x81, 0xfe, big.length >> 8, big.length & 0xff, 0, 0, 0, 0]), big]));
  assert.ok(await closedWithin(own.sock, 10000), 'a 5000-byte message closes the connection');
  // The page is one; seven more (no Origin: not a browser) make eight, the ninth is refused.
  const extra = [];
  try {
    for (let i = 0; i < 7; ++i) {
      const x = await until(`page ${i + 2} of 8 (slots of closed connections given back)`, async () => {
        const c = await upgrade(port, [host]);
        if (c.status === 101) return c;
        c.sock.destroy();
        return null;
      });
      extra.push(x);
    }
    const ninth = await upgrade(port, [host]);
    ninth.sock.destroy();
    step(`eight pages open: a ninth gets ${ninth.status}`);
    assert.equal(ninth.status, 503, 'a ninth page is refused');
  } finally {
    for (const x of extra) x.sock.destroy();
  }

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
