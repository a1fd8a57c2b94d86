// Browser test of the live view: sim_server on the liver-grasp scene, tactus-viewer, and headless
// Chromium (Debian's /usr/bin/chromium driven over the DevTools protocol by puppeteer-core; no
// browser download). Asserts that
//   1. the page receives frames and the canvas shows the organ: in the organ's projected screen
//      rectangle most pixels differ from the background and the shading has many colours;
//   2. the status panel updates (its figures change over a second);
//   3. a simulation restart is survived: sim_server is killed (SIGKILL, a crash), the page says
//      the simulation stopped, a new sim_server starts, and the page shows new frames again.
// Saves screenshots (before/after the restart) into --out. Exit 0 pass, 1 fail, 77 skip (no
// Chromium or no page build).
//
// node viewer_test.mjs --build BUILD_DIR --source SOURCE_DIR --node-modules DIR --out DIR
//                      [--scene SCENE.yaml] [--screenshot PATH] [--haptic 1]
import { spawn } from 'node:child_process';
import { createRequire } from 'node:module';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';

const SKIP = 77;
const args = Object.fromEntries(
  process.argv.slice(2).reduce((acc, a, i, all) => (a.startsWith('--') ? [...acc, [a.slice(2), all[i + 1]]] : acc), []));
const build = args.build, source = args.source;
const out = args.out || path.join(build, 'viewer_test');
const scene = args.scene || path.join(source, 'scenes/liver_grasp.yaml');
const chromium = process.env.TACTUS_CHROMIUM || ['/usr/bin/chromium', '/usr/bin/chromium-browser']
  .find((p) => fs.existsSync(p));
const t0 = Date.now();
const log = (...m) => console.log(`[${((Date.now() - t0) / 1000).toFixed(1)} s]`, ...m);

if (!chromium) {
  console.log('SKIP: no Chromium (/usr/bin/chromium); scripts/install_deps.sh installs it');
  process.exit(SKIP);
}
let puppeteer;
try {
  puppeteer = createRequire(path.join(args['node-modules'], 'x.js'))('puppeteer-core');
} catch (e) {
  console.log(`SKIP: puppeteer-core not found in ${args['node-modules']} (page not built?)`);
  process.exit(SKIP);
}
fs.mkdirSync(out, { recursive: true });

const segment = `tactus_viewer_test_${process.pid}`;
const children = [];
function start(name, exe, argv) {
  const logFile = fs.openSync(path.join(out, `${name}.log`), 'a');
  const p = spawn(exe, argv, { stdio: ['ignore', 'pipe', logFile] });
  p.stdoutText = '';
  p.stdout.on('data', (d) => { p.stdoutText += d; fs.appendFileSync(path.join(out, `${name}.log`), d); });
  children.push(p);
  return p;
}
function startSim() {
  return start('sim_server', path.join(build, 'sim_server/sim_server'), [scene, '--segment', segment]);
}
// --haptic 1: also a haptic_server whose simulated hand replays the scene's trajectory (fills the
// haptic panels; used for the screenshot in scenes/screenshots)
async function startHaptic() {
  const csv = path.join(out, 'trajectory.csv');
  await new Promise((resolve) => spawn(path.join(build, 'sim_server/sim_server'),
    [scene, '--overwrite', '--export-trajectory', csv], { stdio: 'ignore' }).on('exit', resolve));
  return start('haptic_server', path.join(build, 'haptic_server/haptic_server'),
    ['--segment', segment, '--device', 'simulated', '--device-option', `trajectory=${csv}`]);
}
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
async function until(what, fn, timeoutMs) {
  const end = Date.now() + timeoutMs;
  for (;;) {
    const v = await fn();
    if (v) return v;
    if (Date.now() > end) throw new Error(`timed out after ${timeoutMs} ms waiting for ${what}`);
    await sleep(100);
  }
}
function cleanup() {
  for (const c of children) { try { c.kill('SIGKILL'); } catch (e) { /* gone */ } }
  try { fs.unlinkSync(`/dev/shm/${segment}`); } catch (e) { /* absent */ }
}
process.on('exit', cleanup);

// Pixels of the organ's screen rectangle in a screenshot (decoded by the page itself).
async function organPixels(page, pngBase64) {
  return page.evaluate(async (b64) => {
    const rect = window.tactusView.organRect();
    if (!rect) return null;
    const img = new Image();
    img.src = 'data:image/png;base64,' + b64;
    await img.decode();
    const c = document.createElement('canvas');
    c.width = img.width; c.height = img.height;
    const g = c.getContext('2d');
    g.drawImage(img, 0, 0);
    const s = img.width / window.innerWidth;
    const x0 = Math.max(0, Math.floor(rect.x * s)), y0 = Math.max(0, Math.floor(rect.y * s));
    const x1 = Math.min(img.width, Math.ceil((rect.x + rect.width) * s));
    const y1 = Math.min(img.height, Math.ceil((rect.y + rect.height) * s));
    if (x1 - x0 < 10 || y1 - y0 < 10) return { tooSmall: true, rect };
    const d = g.getImageData(x0, y0, x1 - x0, y1 - y0).data;
    const bg = [0x1d, 0x21, 0x27];
    let differ = 0;
    const colours = new Set();
    for (let i = 0; i < d.length; i += 4) {
      const diff = Math.abs(d[i] - bg[0]) + Math.abs(d[i + 1] - bg[1]) + Math.abs(d[i + 2] - bg[2]);
      if (diff > 24) {
        ++differ;
        colours.add((d[i] >> 3) << 10 | (d[i + 1] >> 3) << 5 | (d[i + 2] >> 3));
      }
    }
    return { rect, pixels: d.length / 4, organFraction: differ / (d.length / 4), colours: colours.size };
  }, pngBase64);
}

function check(cond, message) {
  if (!cond) throw new Error(message);
  log('ok:', message);
}

async function screenshotAndCheck(page, file) {
  const b64 = await page.screenshot({ encoding: 'base64', type: 'png' });
  fs.writeFileSync(file, Buffer.from(b64, 'base64'));
  const px = await organPixels(page, b64);
  log(`screenshot ${file}:`, JSON.stringify(px));
  check(px && !px.tooSmall, 'the organ covers a visible screen region');
  check(px.organFraction > 0.3, `organ pixels differ from the background (${(100 * px.organFraction).toFixed(0)}% of its rectangle)`);
  check(px.colours > 12, `the organ is shaded, not flat (${px.colours} distinct colours)`);
  return px;
}

let browser;
let failed = false;
try {
  let sim = startSim();
  if (args.haptic === '1') await startHaptic();
  const viewer = start('viewer', path.join(build, 'tools/viewer/tactus-viewer'),
    ['--segment', segment, '--port', '0']);
  const url = await until('the viewer URL', () => (viewer.stdoutText.match(/http:\/\/127\.0\.0\.1:\d+\//) || [])[0], 10000);
  log('viewer at', url);

  const profile = fs.mkdtempSync(path.join(os.tmpdir(), 'tactus-chromium-'));
  browser = await puppeteer.launch({
    executablePath: chromium,
    headless: true,
    userDataDir: profile,
    args: ['--no-sandbox', '--disable-gpu', '--disable-background-networking',
      '--disable-component-update', '--disable-sync', '--no-first-run',
      '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--window-size=1280,720'],
    defaultViewport: { width: 1280, height: 720 },
  });
  const page = await browser.newPage();
  page.on('console', (m) => fs.appendFileSync(path.join(out, 'browser.log'), `${m.type()}: ${m.text()}\n`));
  page.on('pageerror', (e) => fs.appendFileSync(path.join(out, 'browser.log'), `pageerror: ${e}\n`));
  await page.goto(url, { waitUntil: 'load' });
  const view = (expr) => page.evaluate(expr);

  // 1. frames arrive and the organ is drawn (let the grasper reach the lobe: sim time > 2.5 s)
  await until('20 frames', () => view('window.tactusView.frames >= 20'), 20000);
  await until('the grasper at the lobe (sim time > 2.5 s)',
    () => view('(window.tactusView.lastStatus?.sim?.time_s ?? 0) > 2.5'), 20000);
  await sleep(300);
  await screenshotAndCheck(page, args.screenshot || path.join(out, 'liver_view.png'));

  // 2. the status panel updates
  const panel = () => view(`['simHz','stepMs','frames','status'].map((id) => document.getElementById(id).textContent).join(' | ')`);
  const before = await panel();
  await sleep(1000);
  const after = await panel();
  log('panel before:', before);
  log('panel after: ', after);
  check(before !== after, 'the status panel text changes');
  check(/\d+(\.\d+)? Hz/.test(after), 'the panel shows the simulation rate');
  const st = await view('window.tactusView.lastStatus');
  check(st.attached && st.state === 'running' && st.sim.hz > 5, `status: running at ${st.sim.hz.toFixed(1)} Hz`);

  // 3. a simulation restart: crash it, see "stopped", start it again, see frames again
  const attachBefore = await view('window.tactusView.attachCount');
  sim.kill('SIGKILL');
  log('sim_server killed');
  await until('the page to report the stopped simulation',
    () => view(`(window.tactusView.lastStatus?.state ?? '') !== 'running' && document.getElementById('banner').textContent.includes('stopped')`), 10000);
  log('banner:', await view(`document.getElementById('banner').textContent`));
  sim = startSim();
  log('sim_server restarted');
  await until('re-attach after the restart',
    () => view(`window.tactusView.attachCount > ${attachBefore} && window.tactusView.lastStatus.state === 'running'`), 20000);
  const framesAtReattach = await view('window.tactusView.frames');
  await until('new frames after the restart', () => view(`window.tactusView.frames >= ${framesAtReattach} + 20`), 15000);
  log('banner:', await view(`document.getElementById('banner').textContent`));
  check(await view('window.tactusView.connected'), 'the page kept (or regained) its connection');
  await screenshotAndCheck(page, path.join(out, 'liver_view_after_restart.png'));
  log('PASS');
} catch (e) {
  failed = true;
  console.error('FAIL:', e.message);
} finally {
  if (browser) await browser.close().catch(() => {});
  cleanup();
}
process.exit(failed ? 1 : 0);
