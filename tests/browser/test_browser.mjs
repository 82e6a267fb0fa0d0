// The browser client (client/web) in a real browser: Debian's Chromium,
// headless, WebGL on its software renderer (SwiftShader), driven through
// puppeteer-core. Two pages (two browser contexts: an account that joins
// by the form, a guest by ?name=) and one cvre-client in one world:
// they see each other where the server puts them, a walk with W is
// followed, a model dropped in one page is drawn from its downloaded mesh
// in the other and announced to the terminal client, a pose set in one
// page arrives in the other, a screenshot of the other's canvas shows the
// scene and the object, and neither page logs an error.
//
//   node tests/browser/test_browser.mjs --bin BUILD_DIR [--web-root DIR]
//
// Prints one line per check and "N passed, M failed"; exits 1 on any
// failure. Everything it starts is stopped at the end, also on failure, and
// a watchdog kills it all after WATCHDOG_MS.
import { spawn, spawnSync } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { parseArgs } from 'node:util';
import zlib from 'node:zlib';

const HERE = path.dirname(fileURLToPath(import.meta.url));
const REPO = path.resolve(HERE, '..', '..');
const MODEL = path.resolve(REPO, '..', 'shared', 'models', 'openings', 'kenney_archway_cliff_cave_stone.glb');
const CHROMIUM = '/usr/bin/chromium';
const WATCHDOG_MS = 90000;
const WAIT_MS = 20000; // the longest any one expected state is waited for
const TOL_M = 0.5; // positions seen by two parties
const MM = 0.001; // pose positions travel in whole millimetres
const QUAT_STEP = 1 / 32767; // and quaternion parts in 32767ths
const VIEW = { width: 640, height: 400 };
const DEPS = 'run `bash tools/deps.sh` (it installs node and runs npm ci in client/web and tests/browser)';

const { values: opt } = parseArgs({
  options: { bin: { type: 'string' }, 'web-root': { type: 'string' }, keep: { type: 'boolean' } },
});
if (!opt.bin) {
  console.error('usage: node test_browser.mjs --bin BUILD_DIR [--web-root DIR] [--keep]');
  process.exit(2);
}
const BIN = path.resolve(opt.bin);
const WEB_ROOT = path.resolve(opt['web-root'] || path.join(REPO, 'client', 'web'));

let puppeteer;
try {
  puppeteer = (await import('puppeteer-core')).default;
} catch (e) {
  console.log(`FAIL setup: puppeteer-core is not installed in tests/browser/node_modules: ${DEPS} (${e.message})`);
  console.log('0 passed, 1 failed');
  process.exit(1);
}
for (const [file, what] of [
  [path.join(WEB_ROOT, 'node_modules', 'three', 'build', 'three.module.js'), `three.js is not installed in ${WEB_ROOT}/node_modules: ${DEPS}`],
  [CHROMIUM, `${CHROMIUM} is missing: ${DEPS}`],
  [MODEL, `the model ${MODEL} is missing (../shared beside the repository)`],
  ...['cvre-server', 'cvre-client', 'cvre-admin', 'cvre-import'].map((b) => [path.join(BIN, b), `${BIN} has no ${b}: build it first`]),
]) {
  if (!fs.existsSync(file)) {
    console.log(`FAIL setup: ${what}`);
    console.log('0 passed, 1 failed');
    process.exit(1);
  }
}

const TMP = fs.mkdtempSync(path.join(os.tmpdir(), 'cvre-browser-'));
const PROFILE = path.join(TMP, 'chromium'); // the browser's profile, removed at the end
const children = []; // every process started, killed by teardown and the watchdog
let browser = null;
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

function killAll() {
  for (const c of children) {
    if (c.exitCode === null && c.signalCode === null) c.kill('SIGKILL');
  }
  const chrome = browser && browser.process();
  if (chrome && chrome.exitCode === null) chrome.kill('SIGKILL');
}
const watchdog = setTimeout(() => {
  console.log(`FAIL watchdog: the run took over ${WATCHDOG_MS / 1000}s; everything killed, logs kept in ${TMP}`);
  console.log('0 passed, 1 failed');
  killAll();
  fs.rmSync(PROFILE, { recursive: true, force: true });
  process.exit(1);
}, WATCHDOG_MS);

/** Calls fn until it returns [true, value]; its [false, why] names what is
 * still missing, for the failure message after timeout ms. */
async function until(what, fn, timeout = WAIT_MS) {
  const end = Date.now() + timeout;
  for (;;) {
    const [ok, detail] = await fn();
    if (ok) return detail;
    if (Date.now() > end) throw new Error(`${what}: not within ${timeout / 1000}s: ${detail}`);
    await sleep(100);
  }
}

/** Waits for a child's exit; its code, or null when it took over ms. */
function exited(proc, ms) {
  if (proc.exitCode !== null || proc.signalCode !== null) return Promise.resolve(proc.exitCode);
  return Promise.race([new Promise((resolve) => proc.once('exit', (code) => resolve(code))), sleep(ms).then(() => null)]);
}

function start(name, file, args) {
  const proc = spawn(path.join(BIN, file), args, { stdio: ['pipe', 'pipe', 'pipe'] });
  children.push(proc);
  proc.stderr.pipe(fs.createWriteStream(path.join(TMP, `${name}.log`)));
  proc.on('error', (e) => console.log(`${name}: ${e.message}`));
  return proc;
}

/** cvre-server on 127.0.0.1 with free ports; the TCP port from the first
 * line of stdout, the web port from the log's "web on" line. */
async function startServer() {
  const db = path.join(TMP, 'cvre.db');
  const proc = start('server', 'cvre-server', ['--port', '0', '--web', '127.0.0.1:0', '--web-root', WEB_ROOT,
    '--db', db, '--spawn-radius', '2']);
  let out = '';
  let log = '';
  proc.stdout.on('data', (d) => { out += d; });
  proc.stderr.on('data', (d) => { log += d; });
  const ports = await until('the server\'s ports in its output', async () => {
    const tcp = /^listening on 127\.0\.0\.1:(\d+)\n/.exec(out);
    const web = /web on http:\/\/127\.0\.0\.1:(\d+)\//.exec(log);
    if (proc.exitCode !== null) throw new Error(`the server exited (${proc.exitCode}): ${log.slice(-1000)}`);
    return [tcp && web, tcp && web ? { tcp: +tcp[1], web: +web[1] } : `stdout ${JSON.stringify(out)}`];
  });
  return { proc, db, ...ports };
}

function addAccount(db, name, password) {
  const p = spawnSync(path.join(BIN, 'cvre-admin'), ['--db', db, 'user', 'add', name, '--password-stdin'],
    { input: `${password}\n`, encoding: 'utf8', timeout: 60000 });
  if (p.status !== 0) throw new Error(`cvre-admin user add ${name}: exit ${p.status}: ${p.stderr}`);
}

/** cvre-client reading commands from a pipe; its JSON lines kept in order. */
function startTerminal(port, name) {
  const proc = start('client', 'cvre-client', ['--port', String(port), '--name', name]);
  const term = { proc, events: [], partial: '' };
  proc.stdout.on('data', (d) => {
    const lines = (term.partial + d).split('\n');
    term.partial = lines.pop();
    for (const line of lines) term.events.push(JSON.parse(line));
  });
  term.send = (line) => proc.stdin.write(`${line}\n`);
  term.first = (kind, pred = () => true) => term.events.find((e) => e.event === kind && pred(e));
  term.wait = (what, kind, pred) => until(`the terminal client: ${what}`, async () => {
    const e = term.first(kind, pred);
    return [!!e, e || `last events ${JSON.stringify(term.events.slice(-3))}`];
  });
  /** Where the terminal client last saw avatar id (snapshots, or its joined event). */
  term.posOf = (id) => {
    for (let i = term.events.length - 1; i >= 0; i--) {
      const e = term.events[i];
      const a = e.event === 'snapshot' && e.avatars.find((x) => x.id === id);
      if (a) return a.pos;
      if (e.event === 'joined' && e.id === id) return e.pos;
    }
    return null;
  };
  return term;
}

const dist = (a, b) => Math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]);
const fmt = (v) => (v ? `[${v.map((x) => x.toFixed(3)).join(', ')}]` : String(v));
const state = (page) => page.evaluate(() => (window.cvre ? window.cvre.state() : null));
/** The avatar's forward and right on the ground for a yaw about +y (0 looks down -z). */
const axes = (yaw) => ({ fwd: [-Math.sin(yaw), 0, -Math.cos(yaw)], right: [Math.cos(yaw), 0, -Math.sin(yaw)] });
const dotXZ = (a, b) => a[0] * b[0] + a[2] * b[2];

/** RGBA pixels of an 8-bit, non-interlaced PNG (colour type 2 or 6). */
function decodePng(buf) {
  if (buf.readUInt32BE(0) !== 0x89504e47) throw new Error('not a PNG');
  let at = 8;
  let width = 0;
  let height = 0;
  let type = 0;
  const idat = [];
  while (at < buf.length) {
    const len = buf.readUInt32BE(at);
    const kind = buf.toString('latin1', at + 4, at + 8);
    const body = buf.subarray(at + 8, at + 8 + len);
    if (kind === 'IHDR') {
      [width, height, type] = [body.readUInt32BE(0), body.readUInt32BE(4), body[9]];
      if (body[8] !== 8 || (type !== 2 && type !== 6) || body[12] !== 0) {
        throw new Error(`unsupported PNG: depth ${body[8]}, colour type ${type}, interlace ${body[12]}`);
      }
    } else if (kind === 'IDAT') {
      idat.push(body);
    }
    at += 12 + len;
  }
  const bpp = type === 6 ? 4 : 3;
  const stride = width * bpp;
  const raw = zlib.inflateSync(Buffer.concat(idat));
  const px = Buffer.alloc(width * height * 4);
  let prev = Buffer.alloc(stride);
  for (let y = 0; y < height; y++) {
    const filter = raw[y * (stride + 1)];
    const line = Buffer.from(raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1)));
    for (let i = 0; i < stride; i++) {
      const a = i >= bpp ? line[i - bpp] : 0;
      const b = prev[i];
      const c = i >= bpp ? prev[i - bpp] : 0;
      let add = 0;
      if (filter === 1) add = a;
      else if (filter === 2) add = b;
      else if (filter === 3) add = (a + b) >> 1;
      else if (filter === 4) {
        const p = a + b - c;
        const [pa, pb, pc] = [Math.abs(p - a), Math.abs(p - b), Math.abs(p - c)];
        add = pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
      } else if (filter !== 0) throw new Error(`bad PNG filter ${filter} on row ${y}`);
      line[i] = (line[i] + add) & 0xff;
    }
    for (let x = 0; x < width; x++) {
      for (let k = 0; k < 4; k++) px[(y * width + x) * 4 + k] = k < bpp ? line[x * bpp + k] : 255;
    }
    prev = line;
  }
  return { width, height, px };
}

/** Resolves after the page drew two more frames. */
const nextFrames = (page) => page.evaluate(() => new Promise((resolve) => {
  requestAnimationFrame(() => requestAnimationFrame(resolve));
}));

/** A page's canvas as its WebGL left it (preserveDrawingBuffer), also
 * written to the temporary directory as FILE. */
async function canvasImage(page, file) {
  const url = await page.evaluate(() => document.getElementById('view').toDataURL('image/png'));
  const png = Buffer.from(url.slice(url.indexOf(',') + 1), 'base64');
  fs.writeFileSync(path.join(TMP, file), png);
  return decodePng(png);
}

const colourDiff = (p, i, q, j) => Math.abs(p[i] - q[j]) + Math.abs(p[i + 1] - q[j + 1]) + Math.abs(p[i + 2] - q[j + 2]);

/** The most common colour of an image (the background) and how many
 * pixels differ from it by more than 24 (summed over r, g, b). */
function backgroundStats(img) {
  const counts = new Map();
  for (let i = 0; i < img.px.length; i += 4) {
    const key = img.px.readUIntBE(i, 3);
    counts.set(key, (counts.get(key) || 0) + 1);
  }
  const bg = [...counts.entries()].reduce((m, e) => (e[1] > m[1] ? e : m))[0];
  const ref = Buffer.from([bg >> 16, (bg >> 8) & 0xff, bg & 0xff]);
  let other = 0;
  for (let i = 0; i < img.px.length; i += 4) if (colourDiff(img.px, i, ref, 0) > 24) other++;
  return { bg: ref.toString('hex'), other };
}

/** The pixels that differ between two images of one size, and their bounding box. */
function changed(a, b) {
  let n = 0;
  const box = [Infinity, Infinity, -1, -1];
  for (let i = 0; i < a.px.length; i += 4) {
    if (colourDiff(a.px, i, b.px, i) <= 24) continue;
    n++;
    const x = (i / 4) % a.width;
    const y = Math.floor(i / 4 / a.width);
    box[0] = Math.min(box[0], x);
    box[1] = Math.min(box[1], y);
    box[2] = Math.max(box[2], x);
    box[3] = Math.max(box[3], y);
  }
  return { n, box };
}

/** Where the model is dropped: right of centre and below the horizon, so
 * onto the ground ahead of the avatar and right of ahead. */
const DROP_AT = { x: Math.round(VIEW.width * 0.6), y: Math.round(VIEW.height * 0.75) };

/** Drops MODEL on page at DROP_AT as a person's drop would come: dragenter,
 * dragover and drop, their DataTransfer holding a File of its bytes. */
function dropModel(page) {
  return page.evaluate((b64, fileName, x, y) => {
    const data = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    const dt = new DataTransfer();
    dt.items.add(new File([data], fileName, { type: 'model/gltf-binary' }));
    const target = document.elementFromPoint(x, y);
    for (const type of ['dragenter', 'dragover', 'drop']) {
      target.dispatchEvent(new DragEvent(type, { bubbles: true, cancelable: true, clientX: x, clientY: y, dataTransfer: dt }));
    }
  }, fs.readFileSync(MODEL).toString('base64'), path.basename(MODEL), DROP_AT.x, DROP_AT.y);
}

const errors = []; // the pages' uncaught errors and console errors
function watchPage(page, label) {
  page.on('pageerror', (e) => errors.push(`${label}: uncaught ${e.message}`));
  page.on('console', (m) => {
    // The browser's own request for /favicon.ico is not the page's doing.
    if (m.type() === 'error' && !(m.location().url || '').endsWith('/favicon.ico')) {
      errors.push(`${label}: console error: ${m.text()} (${m.location().url || 'no url'})`);
    }
  });
}

/** The avatar that page sees with that id, or null. */
const seen = (s, id) => (s && s.avatars.find((a) => a.id === id)) || null;

// The world as the checks build it: server, terminal client, pages, and
// the errors each page is expected to show (a refused login, a refused upload).
const w = { expected: [[], []] };
const checks = [];
const check = (name, fn) => checks.push({ name, fn });

check('webgl', async () => {
  w.srv = await startServer();
  w.password = 'pw-alice-1';
  addAccount(w.srv.db, 'alice', w.password);
  w.term = startTerminal(w.srv.tcp, 'term');
  w.termJoin = await w.term.wait('join_ok', 'join_ok');
  const args = ['--use-angle=swiftshader', '--enable-unsafe-swiftshader'];
  if (process.getuid && process.getuid() === 0) args.push('--no-sandbox'); // root has no user namespace sandbox
  browser = await puppeteer.launch({ executablePath: CHROMIUM, headless: true, args, defaultViewport: VIEW,
    userDataDir: PROFILE });
  w.pages = [];
  for (const label of ['page 1', 'page 2']) {
    const ctx = await browser.createBrowserContext();
    const page = await ctx.newPage();
    watchPage(page, label);
    w.pages.push(page);
  }
  w.base = `http://127.0.0.1:${w.srv.web}/`;
  await Promise.all([w.pages[0].goto(w.base), w.pages[1].goto(`${w.base}?name=bob`)]);
  const renderer = await w.pages[0].evaluate(() => {
    const gl = document.createElement('canvas').getContext('webgl2');
    const info = gl && gl.getExtension('WEBGL_debug_renderer_info');
    return info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : null;
  });
  if (!renderer) throw new Error('no WebGL 2 context in headless Chromium (flags: ' + args.join(' ') + ')');
});

/** Joins page by its form, once the form is shown. */
async function fillForm(page, name, password) {
  await page.waitForSelector('#name', { visible: true, timeout: WAIT_MS }).catch(() => {
    throw new Error('the page at / shows no #name field to join with');
  });
  await page.$eval('#name', (el) => { el.value = ''; });
  await page.$eval('#password', (el) => { el.value = ''; });
  await page.type('#name', name);
  await page.type('#password', password);
  await page.click('#join');
}

check('wrong_password', async () => {
  const p1 = w.pages[0];
  await fillForm(p1, 'alice', `${w.password}-wrong`);
  w.expected[0] = await until('page 1 shows the refused login in #errors and its form again', async () => {
    const s = await state(p1);
    const form = await p1.$eval('#name', (el) => el.offsetParent !== null);
    return [s.errors.length > 0 && form && s.status !== 'joined', s.errors.length ? s.errors : `state ${JSON.stringify(s)}`];
  });
  console.log(`     page 1 says: ${w.expected[0].join(' / ')}`);
});

check('join_and_see', async () => {
  const [p1, p2] = w.pages;
  const joined = async (page, label) => until(`${label} joins`, async () => {
    const s = await state(page);
    return [s && s.status === 'joined' && s.self, s && s.status === 'joined' ? s : `state ${JSON.stringify(s)}`];
  });
  // Always in this order, so that the seeded spawn points and the picture
  // are the same in every run.
  const s2 = await joined(p2, 'page 2 (?name=bob)');
  await fillForm(p1, 'alice', w.password);
  const s1 = await joined(p1, 'page 1 (form, account alice)');
  if (s1.self.name !== 'alice' || s2.self.name !== 'bob') throw new Error(`self names ${s1.self.name}, ${s2.self.name}`);
  w.ids = [s1.self.id, s2.self.id];
  const termId = w.termJoin.id;
  const termPos = w.termJoin.pos; // it never moves
  // Each page sees the other and the terminal client where they stand; the
  // terminal client sees both pages where they say they are.
  for (const [page, label, other, otherName] of [[p1, 'page 1', p2, 'bob'], [p2, 'page 2', p1, 'alice']]) {
    await until(`${label} sees ${otherName} and term within ${TOL_M} m`, async () => {
      const [s, o] = [await state(page), await state(other)];
      const a = seen(s, o.self.id);
      const t = seen(s, termId);
      const ok = a && t && a.name === otherName && t.name === 'term' && dist(a.pos, o.self.pos) <= TOL_M
        && dist(t.pos, termPos) <= TOL_M;
      return [ok, `${otherName} ${a ? `${a.name} at ${fmt(a.pos)}` : 'absent'} (its own ${fmt(o.self.pos)}), `
        + `term ${t ? `at ${fmt(t.pos)}` : 'absent'} (its own ${fmt(termPos)}); avatars ${JSON.stringify(s.avatars)}`];
    });
  }
  for (const [page, name] of [[p1, 'alice'], [p2, 'bob']]) {
    const s = await state(page);
    await w.term.wait(`joined of ${name}`, 'joined', (e) => e.id === s.self.id && e.name === name);
    await until(`the terminal client sees ${name} within ${TOL_M} m`, async () => {
      const [pos, own] = [w.term.posOf(s.self.id), (await state(page)).self.pos];
      return [pos && dist(pos, own) <= TOL_M, `at ${fmt(pos)}, its own ${fmt(own)}`];
    });
  }
  // three's VRButton: "ENTER VR" where WebXR can start a session, else
  // a disabled button or a note saying why not (headless: no headset).
  const vr = await until('page 2 shows one VR button (three\'s VRButton)', async () => {
    const texts = await p2.$$eval('button, a', (els) => els.map((e) => e.textContent).filter((t) => /\bVR\b|WEBXR/.test(t)));
    return [texts.length === 1, texts.length === 1 ? texts[0] : JSON.stringify(texts)];
  });
  console.log(`     page 2's VR button says ${JSON.stringify(vr)}`);
  for (const [page, label] of [[p1, 'page 1'], [p2, 'page 2']]) {
    await until(`${label}'s #users lists alice, bob and term`, async () => {
      const names = await page.$$eval('#users li', (lis) => lis.map((li) => li.textContent));
      return [['alice', 'bob', 'term'].every((n) => names.some((t) => t.includes(n))), JSON.stringify(names)];
    });
  }
});

check('walk', async () => {
  const [p1, p2] = w.pages;
  const from = (await state(p1)).self.pos;
  await p1.bringToFront();
  await p1.keyboard.down('KeyW');
  try {
    await until('page 1 walks 1 m while W is held', async () => {
      const pos = (await state(p1)).self.pos;
      return [dist(pos, from) >= 1, `from ${fmt(from)} to ${fmt(pos)}`];
    });
  } finally {
    await p1.keyboard.up('KeyW');
  }
  // Once it stands still, page 2 and the terminal client see it there.
  let last = null;
  const to = await until('page 1 stops after W is released', async () => {
    const pos = (await state(p1)).self.pos;
    const still = last && dist(pos, last) < 1e-4;
    last = pos;
    await sleep(200);
    return [still, pos];
  });
  const yaw = await until('page 2 has page 1\'s facing', async () => {
    const a = seen(await state(p2), w.ids[0]);
    return [a && a.pose && Number.isFinite(a.pose.yaw), a && a.pose ? a.pose.yaw : `pose ${JSON.stringify(a && a.pose)}`];
  });
  const step = [to[0] - from[0], 0, to[2] - from[2]];
  const ahead = dotXZ(step, axes(yaw).fwd);
  if (ahead < 0.9 * Math.hypot(step[0], step[2])) {
    throw new Error(`W walked ${fmt(step)}, not forward for yaw ${yaw.toFixed(3)} (${ahead.toFixed(3)} m ahead)`);
  }
  await until(`page 2 sees page 1 within ${TOL_M} m of where it stopped`, async () => {
    const a = seen(await state(p2), w.ids[0]);
    return [a && dist(a.pos, to) <= TOL_M, `at ${fmt(a && a.pos)}, page 1 at ${fmt(to)}`];
  });
  await until(`the terminal client sees page 1 within ${TOL_M} m of where it stopped`, async () => {
    const pos = w.term.posOf(w.ids[0]);
    return [pos && dist(pos, to) <= TOL_M, `at ${fmt(pos)}, page 1 at ${fmt(to)}`];
  });
  w.yaw1 = yaw;
  w.pos1 = to;
});

check('drop_model', async () => {
  const [p1, p2] = w.pages;
  // The scene without the object, for the screenshot check: page 2's view
  // once it is still (two frames alike), so that what changes after the
  // drop is the object.
  let prev = null;
  w.before = await until('page 2\'s view stands still before the drop', async () => {
    await nextFrames(p2);
    const img = await canvasImage(p2, 'before-drop.png');
    const moved = prev ? changed(prev, img).n : -1;
    prev = img;
    return [moved === 0, moved === 0 ? img : `${moved} pixels changed between two frames`];
  });
  w.avatarsBefore = JSON.stringify((await state(p2)).avatars.map((a) => [a.id, a.pos]));
  const name = path.basename(MODEL);
  await dropModel(p1);
  const obj = await w.term.wait(`object event for ${name}`, 'object', (e) => e.owner === 'alice');
  await until(`page 1's #status names object ${obj.id}`, async () => {
    const text = await p1.$eval('#status', (el) => el.textContent).catch((e) => `no #status (${e.message})`);
    return [new RegExp(`\\b${obj.id}\\b`).test(text), JSON.stringify(text)];
  });
  const o2 = await until(`page 2 draws object ${obj.id}`, async () => {
    const o = (await state(p2)).objects.find((x) => x.id === obj.id);
    return [o && o.meshTriangles > 0, o || 'not in state().objects'];
  });
  if (o2.meshHash !== obj.mesh) throw new Error(`page 2's meshHash ${o2.meshHash}, the server's ${obj.mesh}`);
  // The mesh's own count: the terminal client fetches and decodes it.
  w.term.send(`fetch ${obj.id} ${path.join(TMP, 'drop.obj')}`);
  const got = await w.term.wait('fetched', 'fetched', (e) => e.object === obj.id);
  if (o2.meshTriangles !== got.triangles || obj.triangles !== got.triangles) {
    throw new Error(`page 2 draws ${o2.meshTriangles} triangles; the object event says ${obj.triangles}, the fetched mesh has ${got.triangles}`);
  }
  // Placed where the drop pointed: on the ground, ahead and right of page 1.
  const lo = [0, 1, 2].map((k) => Math.min(...obj.boxes.map((b) => b[k])));
  const hi = [0, 1, 2].map((k) => Math.max(...obj.boxes.map((b) => b[k + 3])));
  const centre = lo.map((v, k) => (v + hi[k]) / 2);
  const off = [centre[0] - w.pos1[0], 0, centre[2] - w.pos1[2]];
  const { fwd, right } = axes(w.yaw1);
  if (Math.abs(lo[1]) > 0.15 || dotXZ(off, fwd) < 0.5 || dotXZ(off, right) < 0.1) {
    throw new Error(`dropped at screen (${DROP_AT.x}, ${DROP_AT.y}) it stands ${fmt(lo)}..${fmt(hi)}: `
      + `${dotXZ(off, fwd).toFixed(2)} m ahead of page 1 and ${dotXZ(off, right).toFixed(2)} m right, `
      + 'not on the ground ahead and to the right');
  }
  w.object = obj;
});

check('screenshot', async () => {
  const p2 = w.pages[1];
  await nextFrames(p2);
  const img = await canvasImage(p2, 'after-drop.png');
  const avatars = JSON.stringify((await state(p2)).avatars.map((a) => [a.id, a.pos]));
  if (avatars !== w.avatarsBefore) throw new Error(`the avatars moved during the drop: ${w.avatarsBefore}, then ${avatars}`);
  const all = img.width * img.height;
  const { bg, other } = backgroundStats(img);
  if (other < all * 0.01) throw new Error(`page 2's canvas is blank: ${other} of ${all} pixels differ from its colour #${bg}`);
  if (img.width !== w.before.width || img.height !== w.before.height) throw new Error('page 2\'s canvas changed size');
  const { n, box } = changed(w.before, img);
  const area = (box[2] - box[0] + 1) * (box[3] - box[1] + 1);
  if (n < 200 || area > all / 2) {
    const where = n ? `, within x ${box[0]}..${box[2]}, y ${box[1]}..${box[3]} (at most half the canvas wanted)` : '';
    throw new Error(`the object in page 2's view: ${n} pixels changed when it came (at least 200 wanted)${where}`);
  }
  w.shot = img;
  console.log(`     page 2's canvas: ${other} of ${all} pixels not #${bg}; the object ${n} pixels within x ${box[0]}..${box[2]}, y ${box[1]}..${box[3]}`);
});

check('show_boxes', async () => {
  const p2 = w.pages[1];
  await p2.click('#show-boxes');
  await nextFrames(p2);
  const img = await canvasImage(p2, 'boxes.png');
  await p2.click('#show-boxes');
  const { n } = changed(w.shot, img);
  if (n < 50) throw new Error(`#show-boxes drew ${n} pixels over the object's view (its collision boxes as wireframes wanted)`);
  console.log(`     #show-boxes: ${n} pixels`);
});

check('pose', async () => {
  const [p1, p2] = w.pages;
  const q = (ax, ay, az, deg) => {
    const s = Math.sin((deg * Math.PI) / 360);
    return [ax * s, ay * s, az * s, Math.cos((deg * Math.PI) / 360)];
  };
  const pose = {
    head: { p: [0.013, 1.612, -0.047], q: q(0, 1, 0, 30) },
    left: { p: [-0.251, 1.203, -0.388], q: q(1, 0, 0, -20) },
    right: { p: [0.262, 1.318, -0.305], q: q(0.6, 0, 0.8, 45) },
  };
  await p1.evaluate((pz) => window.cvre.setXRPose(pz), pose);
  const near = (got, want) => got && ['head', 'left', 'right'].every((k) => got[k]
    && got[k].p.every((v, i) => Math.abs(v - want[k].p[i]) <= MM / 2 + 1e-6)
    && (got[k].q.every((v, i) => Math.abs(v - want[k].q[i]) <= QUAT_STEP + 1e-6)
      || got[k].q.every((v, i) => Math.abs(v + want[k].q[i]) <= QUAT_STEP + 1e-6))); // q and -q: one rotation
  await until('page 2 gets page 1\'s pose within quantization', async () => {
    const a = seen(await state(p2), w.ids[0]);
    return [a && near(a.pose, pose), `got ${JSON.stringify(a && a.pose)}, set ${JSON.stringify(pose)}`];
  });
  await w.term.wait('page 1\'s pose', 'pose', (e) => e.id === w.ids[0] && e.head
    && e.head.pos.every((v, i) => Math.abs(v - pose.head.p[i]) <= MM / 2 + 1e-6));
});

check('guest_upload_refused', async () => {
  const p2 = w.pages[1];
  const shown = (await state(p2)).errors.length;
  await dropModel(p2);
  w.expected[1] = await until('page 2 (a guest) shows its upload refused in #errors', async () => {
    const t = await p2.$$eval('#errors li', (lis) => lis.map((li) => li.textContent.trim()));
    const s = await state(p2);
    return [t.length > 0 && s.errors.length > shown, s.errors.slice(shown)];
  });
  // The server answered the upload before the refusal was shown: an object
  // made from it would reach the terminal client before the pong to a
  // ping it sends now.
  w.term.send('ping');
  const pong = w.term.events.length;
  await w.term.wait('pong', 'pong', (e) => w.term.events.indexOf(e) >= pong);
  if (w.term.first('object', (e) => e.owner === 'bob')) {
    throw new Error(`a guest's drop became an object (page 2 said ${JSON.stringify(w.expected[1])})`);
  }
  console.log(`     page 2 says: ${w.expected[1].join(' / ')}`);
});

check('page_errors', async () => {
  for (const [i, label] of ['page 1', 'page 2'].entries()) {
    const other = (await state(w.pages[i])).errors.filter((e) => !w.expected[i].includes(e));
    if (other.length) errors.push(`${label} shows errors: ${JSON.stringify(other)}`);
  }
  if (errors.length) throw new Error(errors.join('; '));
});

check('clean_exit', async () => {
  await browser.close();
  browser = null;
  w.term.send('quit');
  const client = await exited(w.term.proc, 10000);
  w.srv.proc.kill('SIGTERM');
  const server = await exited(w.srv.proc, 10000);
  if (client !== 0 || server !== 0) throw new Error(`cvre-client exit ${client}, cvre-server exit ${server} (logs in ${TMP})`);
});

const t0 = Date.now();
let failed = 0;
try {
  for (const [i, { name, fn }] of checks.entries()) {
    const t = Date.now();
    try {
      await fn();
      console.log(`ok   ${name} (${((Date.now() - t) / 1000).toFixed(1)}s)`);
    } catch (e) {
      failed = checks.length - i;
      console.log(`FAIL ${name}: ${e.message}`);
      for (const rest of checks.slice(i + 1)) console.log(`FAIL ${rest.name}: not run, ${name} failed`);
      if (errors.length && name !== 'page_errors') console.log(`page errors so far: ${errors.join('; ')}`);
      break;
    }
  }
} finally {
  clearTimeout(watchdog);
  if (browser) await Promise.race([browser.close(), sleep(5000)]);
  killAll();
  fs.rmSync(PROFILE, { recursive: true, force: true });
}
console.log(`browser test: ${((Date.now() - t0) / 1000).toFixed(1)}s`);
console.log(`${checks.length - failed} passed, ${failed} failed`);
if (failed || opt.keep) console.log(`logs and page 2's canvas kept in ${TMP}`);
else fs.rmSync(TMP, { recursive: true, force: true });
process.exit(failed ? 1 : 0);
