/*
 * upload.js: a model file dropped on the page becomes an object where the
 * user points. The file goes up as OBJECT_UPLOAD_BEGIN, CHUNKs of
 * PROTO_CHUNK_MAX bytes and END (PROTOCOL.md, section 5), y up at unit
 * scale, with the extension as the format hint, and then stood on the
 * spot by its boxes (upload_object); the chunks are paced by
 * the socket's send buffer so that moves keep flowing beside a large
 * file. One upload at a time, as the server allows.
 */
import * as proto from './proto.js';

const { S } = proto;

/* The formats the server's importer reads, by extension. */
const UPLOAD_FORMATS = new Set(['obj', 'stl', 'ply', 'glb']);
/* Bytes queued on the socket before the next chunk waits. */
const UPLOAD_WINDOW = 4 * proto.PROTO_CHUNK_MAX;
/* Upload ids are ours to pick (non-zero); the counter starts high, apart
 * from the object ids the server gives, though the codes tell them apart
 * anyway (world.js). */
const UPLOAD_ID_BASE = 0x40000000;
/* Where a drop that points at nothing places the object: this far in
 * front of the avatar, metres. */
const UPLOAD_AHEAD = 3;

/*
 * The upload state. io holds: send(frame) -> bool, buffered() -> bytes
 * queued on the socket, status(words), problem(words).
 */
export function upload_new(io) {
    return { io, next_id: UPLOAD_ID_BASE, cur: null, placing: null };
}

/* Where a drop places an object: the picked point, else UPLOAD_AHEAD in
 * front of pos along yaw, on the ground. */
export function upload_place(picked, pos, yaw) {
    if (picked)
        return picked;
    return [pos[0] - Math.sin(yaw) * UPLOAD_AHEAD, 0, pos[2] - Math.cos(yaw) * UPLOAD_AHEAD];
}

/* A file name as an object name: within the text rule (controls become
 * '?'); proto cuts it to PROTO_OBJECT_NAME_MAX bytes. */
function label_of(name) {
    return name.replace(/[\u0000-\u001f\u007f]/g, '?') || 'model';
}

/*
 * Starts uploading file (a File) to be placed at pos. Refuses, in words,
 * a second upload while one runs, an empty file and a format the
 * importer does not read. The answer comes to upload_object or
 * upload_rejected.
 */
export async function upload_start(u, file, pos) {
    const dot = file.name.lastIndexOf('.');
    const ext = dot >= 0 ? file.name.slice(dot + 1).toLowerCase() : '';
    if (u.cur) {
        u.io.problem(`${file.name}: an upload is already under way (${u.cur.name}); one at a time`);
        return;
    }
    if (!UPLOAD_FORMATS.has(ext)) {
        u.io.problem(`${file.name}: not a model this server imports (obj, stl, ply or glb)`);
        return;
    }
    if (file.size === 0 || file.size > 0xffffffff) {
        u.io.problem(`${file.name}: ${file.size === 0 ? 'the file is empty' : 'the file is too large'}`);
        return;
    }
    const cur = { id: u.next_id++, name: file.name, size: file.size, sent: 0, pos, done: false };
    u.cur = cur;
    let bytes;
    try {
        bytes = new Uint8Array(await file.arrayBuffer());
    } catch (e) {
        upload_finish(u, cur);
        u.io.problem(`${file.name}: could not be read (${e.message})`);
        return;
    }
    if (!u.io.send(proto.proto_put_upload_begin(cur.id, bytes.length, label_of(file.name), ext, 0, 1))) {
        upload_finish(u, cur);
        u.io.problem(`${file.name}: not connected`);
        return;
    }
    u.io.status(`uploading ${file.name}: 0 of ${bytes.length} bytes`);
    chunks(u, cur, bytes);
}

/* Sends chunks while the socket's queue is short, then waits a little. */
function chunks(u, cur, bytes) {
    if (cur.done)
        return;
    while (cur.sent < bytes.length && u.io.buffered() < UPLOAD_WINDOW) {
        const n = Math.min(proto.PROTO_CHUNK_MAX, bytes.length - cur.sent);
        if (!u.io.send(proto.proto_put_upload_chunk(cur.id, cur.sent, bytes.subarray(cur.sent, cur.sent + n)))) {
            upload_finish(u, cur);
            return;
        }
        cur.sent += n;
    }
    if (cur.sent < bytes.length) {
        u.io.status(`uploading ${cur.name}: ${cur.sent} of ${bytes.length} bytes (${Math.floor(100 * cur.sent / bytes.length)} %)`);
        setTimeout(() => chunks(u, cur, bytes), 20);
        return;
    }
    u.io.send(proto.proto_put_upload_end(cur.id, cur.pos, 0, 1));
    u.io.status(`${cur.name}: all ${bytes.length} bytes sent; the server is importing it`);
}

function upload_finish(u, cur) {
    cur.done = true;
    if (u.cur === cur)
        u.cur = null;
}

/* The bottom centre of the box around an OBJECT_INFO's boxes. */
function base_of(info) {
    const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (const b of info.boxes)
        for (let k = 0; k < 3; k++) {
            lo[k] = Math.min(lo[k], b.min[k]);
            hi[k] = Math.max(hi[k], b.max[k]);
        }
    return [(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2];
}

/*
 * OBJECT_INFO with our upload id: the upload became an object, its origin
 * where the user pointed. Many models do not sit on their origin (a desk
 * beside it, a statue below it), so one OBJECT_PLACE then moves the
 * object by the difference between that point and the bottom centre of
 * its boxes, as cvre-client's `import --anchor base` does: the model
 * stands where it was dropped.
 */
export function upload_object(u, info) {
    const cur = u.cur;
    if (!cur || info.upload_id !== cur.id)
        return;
    upload_finish(u, cur);
    const base = info.boxes.length ? base_of(info) : cur.pos;
    const d = cur.pos.map((c, k) => c - base[k]);
    const at = info.at.pos.map((c, k) => c + d[k]);
    u.io.status(`${cur.name} is object ${info.object_id} (${info.tri_count} triangles), ` +
        `at (${cur.pos.map((c) => c.toFixed(2)).join(', ')})`);
    if (Math.hypot(d[0], d[1], d[2]) > 0.001 &&
        u.io.send(proto.proto_put_object_place(info.object_id, at, info.at.yaw, info.at.scale)))
        u.placing = { object_id: info.object_id, name: cur.name };
}

/* OBJECT_REJECTED of our upload, or of the placement after it: told
 * once, in words; the refusals of the chunks still on their way after
 * the first are dropped. */
export function upload_rejected(u, m) {
    if (u.placing && m.request_id === u.placing.object_id) {
        u.io.problem(`${u.placing.name} (object ${m.request_id}) stays at its origin: ` +
            `${proto.proto_strerror(m.code)}${m.message ? ' (' + m.message + ')' : ''}`);
        u.placing = null;
        return;
    }
    const cur = u.cur;
    if (!cur || m.request_id !== cur.id)
        return;
    upload_finish(u, cur);
    const why = m.code === S.GUEST
        ? 'guests may not upload; join with an account and its password'
        : proto.proto_strerror(m.code);
    u.io.problem(`upload of ${cur.name} refused: ${why}${m.message && m.message !== why ? ' (' + m.message + ')' : ''}`);
    u.io.status(`upload of ${cur.name} refused`);
}
