/*
 * proto.js: the cvre wire codec for the browser, after protocol/proto.c
 * and protocol/proto_mesh.c (PROTOCOL.md gives the bytes).
 *
 * Over a WebSocket every binary message is exactly one frame. Decoding
 * checks what the C codec checks on the frames a client receives: the
 * exact layout (SHORT, TRAILING), the text rule for strings, finite
 * floats and every range, in field order, the first failure winning.
 * Encoding builds one frame per call, as an ArrayBuffer to send whole.
 * Only the frames this client sends have an encoder, and only those it
 * receives a decoder.
 */

export const PROTO_VERSION = 2;
export const PROTO_MAGIC = 0x45525643; /* "CVRE" read as a little-endian u32 */
export const PROTO_HEADER_SIZE = 6;
export const PROTO_MAX_LEN = 65536;
export const PROTO_NAME_MAX = 32;
export const PROTO_MESSAGE_MAX = 200;
export const PROTO_TOKEN_SIZE = 16;
export const PROTO_PASSWORD_MAX = 128;
export const PROTO_RESUME_TOKEN_SIZE = 32;
export const PROTO_BOX_MIN = Math.fround(0.1);
export const PROTO_BOX_MAX = 4.0;
export const PROTO_CHUNK_MAX = 16384;
export const PROTO_OBJECT_NAME_MAX = 64;
export const PROTO_FORMAT_MAX = 8;
export const PROTO_OBJECT_BOXES_MAX = 1024;
export const PROTO_SCALE_MIN = Math.fround(0.001);
export const PROTO_SCALE_MAX = 1000.0;
export const PROTO_MESH_HASH_SIZE = 32;
export const PROTO_MESH_CHUNK_MAX = 16384;
export const PROTO_QUAT_ONE = 32767;
export const PROTO_PITCH_MAX = Math.fround(1.5707964);
export const PROTO_POSE_HEAD_RANGE_MM = 4000;
export const PROTO_POSE_REACH_MM = 1500;
export const PROTO_QUAT_NORM2_TOLERANCE = 0.02;
export const PROTO_POSE_PARTS = 3; /* head, left hand, right hand */
export const PROTO_POSE_HEAD = 0;
export const PROTO_POSE_LEFT = 1;
export const PROTO_POSE_RIGHT = 2;

/* protocol/proto_mesh.h */
export const PROTO_MESH_HEAD_SIZE = 32;
export const PROTO_MESH_STEPS = 65535;
export const PROTO_MESH_TRIS_MAX = 16777216;
export const PROTO_MESH_SMALL_VERTS = 65536;

export const T = Object.freeze({
    HELLO: 1, WELCOME: 2, JOIN: 3, JOIN_OK: 4, MOVE: 5, SNAPSHOT: 6,
    AVATAR_JOINED: 7, AVATAR_LEFT: 8, ERROR: 9, PING: 10, PONG: 11, BYE: 12,
    AVATAR_POSE: 13, OBJECT_UPLOAD_BEGIN: 32, OBJECT_UPLOAD_CHUNK: 33,
    OBJECT_UPLOAD_END: 34, OBJECT_PLACE: 35, OBJECT_REMOVE: 37, OBJECT_INFO: 38,
    OBJECT_REMOVED: 39, OBJECT_REJECTED: 40, MESH_REQUEST: 41, MESH_CHUNK: 42,
    COLLISION: 48,
});

/* Status codes (proto.h enum proto_status). */
export const S = Object.freeze({
    OK: 0, INCOMPLETE: 1, FRAME_EMPTY: 16, FRAME_TOO_LONG: 17, UNKNOWN_TYPE: 18,
    SHORT: 19, TRAILING: 20, BAD_STRING: 21, NOT_FINITE: 22, BAD_VALUE: 23,
    BAD_MAGIC: 24, VERSION: 25, UNEXPECTED: 26, ALREADY_JOINED: 27, TRUNCATED: 28,
    TIMEOUT: 29, SERVER_FULL: 30, BAD_SEQ: 32, INTERNAL: 34, UPLOAD: 35,
    IMPORT: 36, NO_OBJECT: 37, NOT_OWNER: 38, GUEST: 39, AUTH: 40,
    AUTH_REQUIRED: 41, RATE_LIMITED: 42, PLACEMENT: 43, STALE_MESH: 44,
});

const STATUS_TEXT = {
    0: 'ok', 1: 'incomplete frame', 16: 'frame length below 2', 17: 'frame too long',
    18: 'unknown message type', 19: 'payload too short', 20: 'trailing bytes after payload',
    21: 'bad string', 22: 'number not finite', 23: 'value out of range', 24: 'bad magic',
    25: 'protocol version not supported', 26: 'unexpected message', 27: 'already joined',
    28: 'connection closed mid-frame', 29: 'timeout', 30: 'server full',
    32: 'move sequence did not increase', 34: 'internal server error', 35: 'upload refused',
    36: 'model could not be imported', 37: 'no such object', 38: 'not the owner',
    39: 'not allowed for guests', 40: 'login failed', 41: 'login required', 42: 'rate limited',
    43: 'placement refused', 44: 'mesh hash does not match',
};

/* Short English description of a status code, as proto_strerror. */
export function proto_strerror(status) {
    return STATUS_TEXT[status] ?? 'unknown status';
}

const TYPE_NAMES = Object.fromEntries(Object.entries(T).map(([k, v]) => [v, k.toLowerCase()]));

/* Name of a message type for messages ("snapshot"), or "unknown". */
export function proto_type_name(type) {
    return TYPE_NAMES[type] ?? 'unknown';
}

/* ---- text -------------------------------------------------------------- */

/* fatal: ill-formed UTF-8 (stray or missing continuation bytes, overlong
 * forms, surrogates, past U+10FFFF) throws, as utf8_next refuses it;
 * ignoreBOM keeps a leading U+FEFF, which is text like any other. */
const utf8_decoder = new TextDecoder('utf-8', { fatal: true, ignoreBOM: true });
const utf8_encoder = new TextEncoder();
const CONTROL = /[\u0000-\u001f\u007f]/;

/* The text of bytes that pass the text rule, or null. */
function text_of(bytes) {
    let s;
    try {
        s = utf8_decoder.decode(bytes);
    } catch {
        return null;
    }
    return CONTROL.test(s) ? null : s;
}

/* The UTF-8 bytes of s cut to at most max bytes at a character boundary,
 * as the C encoder's str_len cuts. */
export function proto_text_bytes(s, max) {
    const b = utf8_encoder.encode(s);
    let n = Math.min(b.length, max);
    while (n > 0 && n < b.length && (b[n] & 0xc0) === 0x80)
        n--;
    return b.subarray(0, n);
}

/* Why a display name would be refused by the server's text rule, in
 * words, or null when it is fine. */
export function proto_name_problem(name) {
    const n = utf8_encoder.encode(name).length;
    if (n === 0)
        return 'a name is needed';
    if (n > PROTO_NAME_MAX)
        return `a name is at most ${PROTO_NAME_MAX} bytes of UTF-8 (this one is ${n})`;
    if (CONTROL.test(name))
        return 'a name may not hold control characters';
    return null;
}

export function proto_hex(bytes) {
    return Array.from(bytes, (b) => b.toString(16).padStart(2, '0')).join('');
}

/* ---- reader ------------------------------------------------------------ */

/* Reads a payload; the first failure sticks and every read after it
 * yields zero, so a decoder reads its whole layout and checks once. */
class reader {
    constructor(bytes) {
        this.bytes = bytes;
        this.dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
        this.at = 0;
        this.err = S.OK;
    }

    get left() {
        return this.bytes.length - this.at;
    }

    reject(status) {
        if (this.err === S.OK)
            this.err = status;
    }

    /* Offset of the next n bytes, consumed; -1 when failed or short. */
    take(n) {
        if (this.err !== S.OK)
            return -1;
        if (n > this.left) {
            this.err = S.SHORT;
            return -1;
        }
        const at = this.at;
        this.at += n;
        return at;
    }

    u8() {
        const at = this.take(1);
        return at < 0 ? 0 : this.dv.getUint8(at);
    }

    u16() {
        const at = this.take(2);
        return at < 0 ? 0 : this.dv.getUint16(at, true);
    }

    i16() {
        const at = this.take(2);
        return at < 0 ? 0 : this.dv.getInt16(at, true);
    }

    u32() {
        const at = this.take(4);
        return at < 0 ? 0 : this.dv.getUint32(at, true);
    }

    u64() {
        const at = this.take(8);
        return at < 0 ? 0n : this.dv.getBigUint64(at, true);
    }

    /* A copy of the next n bytes (the payload's buffer is not kept). */
    bytes_copy(n) {
        const at = this.take(n);
        return at < 0 ? new Uint8Array(n) : this.bytes.slice(at, at + n);
    }

    /* Every float on the wire must be finite: looked at in its bits. */
    f32() {
        const at = this.take(4);
        if (at < 0)
            return 0;
        if ((this.dv.getUint32(at, true) & 0x7f800000) === 0x7f800000) {
            this.reject(S.NOT_FINITE);
            return 0;
        }
        return this.dv.getFloat32(at, true);
    }

    vec3() {
        return [this.f32(), this.f32(), this.f32()];
    }

    /* An avatar box, each edge in [PROTO_BOX_MIN, PROTO_BOX_MAX], failing
     * at the edge that is wrong. */
    box() {
        const b = [];
        for (let i = 0; i < 3; i++) {
            b.push(this.f32());
            if (!(b[i] >= PROTO_BOX_MIN && b[i] <= PROTO_BOX_MAX))
                this.reject(S.BAD_VALUE);
        }
        return b;
    }

    /* A u8 length and min..max bytes of text; a missing length byte is
     * SHORT, the rest BAD_STRING. */
    str(min, max) {
        const n = this.u8();
        if (this.err !== S.OK)
            return '';
        const s = n <= this.left ? text_of(this.bytes.subarray(this.at, this.at + n)) : null;
        if (s === null || n < min || n > max) {
            this.reject(S.BAD_STRING);
            return '';
        }
        this.take(n);
        return s;
    }

    /* A non-zero id. */
    id() {
        const v = this.u32();
        if (v === 0)
            this.reject(S.BAD_VALUE);
        return v;
    }

    transform() {
        const pos = this.vec3(), yaw = this.f32(), scale = this.f32();
        if (!(scale >= PROTO_SCALE_MIN && scale <= PROTO_SCALE_MAX))
            this.reject(S.BAD_VALUE);
        return { pos, yaw, scale };
    }

    /* A pose (PROTOCOL.md, section 1), each part checked right after it
     * is read, as proto.c's get_pose. */
    pose() {
        const p = { yaw: this.f32(), pitch: this.f32(), parts: 0, pos: [], rot: [] };
        if (!(p.pitch >= -PROTO_PITCH_MAX && p.pitch <= PROTO_PITCH_MAX))
            this.reject(S.BAD_VALUE);
        p.parts = this.u8();
        if (p.parts >> PROTO_POSE_PARTS || (p.parts && !(p.parts & 1)))
            this.reject(S.BAD_VALUE);
        for (let k = 0; k < PROTO_POSE_PARTS; k++) {
            p.pos.push([0, 0, 0]);
            p.rot.push([0, 0, 0, 0]);
        }
        for (let k = 0; k < PROTO_POSE_PARTS && this.err === S.OK; k++) {
            if (!((p.parts >> k) & 1))
                continue;
            let d2 = 0, q2 = 0;
            for (let i = 0; i < 3; i++) {
                p.pos[k][i] = this.i16();
                const d = p.pos[k][i] - (k === PROTO_POSE_HEAD ? 0 : p.pos[PROTO_POSE_HEAD][i]);
                if (k === PROTO_POSE_HEAD && Math.abs(d) > PROTO_POSE_HEAD_RANGE_MM)
                    this.reject(S.BAD_VALUE);
                d2 += d * d;
            }
            if (k !== PROTO_POSE_HEAD && d2 > PROTO_POSE_REACH_MM * PROTO_POSE_REACH_MM)
                this.reject(S.BAD_VALUE);
            for (let i = 0; i < 4; i++) {
                p.rot[k][i] = this.i16();
                q2 += p.rot[k][i] * p.rot[k][i];
            }
            if (!(Math.abs(q2 / (PROTO_QUAT_ONE * PROTO_QUAT_ONE) - 1) <= PROTO_QUAT_NORM2_TOLERANCE))
                this.reject(S.BAD_VALUE);
        }
        return p;
    }
}

/* ---- decoding ---------------------------------------------------------- */

function decode_welcome(r) {
    const m = { version: r.u16(), session_id: r.u64(), token: r.bytes_copy(PROTO_TOKEN_SIZE) };
    m.tick_hz = r.u16();
    if (m.tick_hz === 0)
        r.reject(S.BAD_VALUE);
    m.aoi_radius = r.f32();
    if (!(m.aoi_radius > 0))
        r.reject(S.BAD_VALUE);
    m.max_speed = r.f32();
    if (!(m.max_speed >= 0))
        r.reject(S.BAD_VALUE);
    m.world_min = r.vec3();
    m.world_max = [];
    for (let i = 0; i < 3; i++) {
        m.world_max.push(r.f32());
        if (!(m.world_max[i] >= m.world_min[i]))
            r.reject(S.BAD_VALUE);
    }
    m.idle_timeout_ms = r.u32();
    if (m.idle_timeout_ms === 0)
        r.reject(S.BAD_VALUE);
    return m;
}

function decode_join_ok(r) {
    const m = { avatar_id: r.u32(), pos: r.vec3(), box: r.box(), token: null };
    if (r.err === S.OK && r.left > 0)
        m.token = r.bytes_copy(PROTO_RESUME_TOKEN_SIZE);
    return m;
}

function decode_snapshot(r) {
    const m = { tick: r.u32(), ack_seq: r.u32(), entries: [] };
    const count = r.u16();
    for (let i = 0; i < count && r.err === S.OK; i++)
        m.entries.push({ id: r.u32(), pos: r.vec3() });
    return m;
}

function decode_object_info(r) {
    const m = { object_id: r.id(), upload_id: r.u32() };
    m.owner = r.str(1, PROTO_NAME_MAX);
    m.name = r.str(1, PROTO_OBJECT_NAME_MAX);
    m.at = r.transform();
    m.ecm_version = r.id();
    m.tri_count = r.u32();
    m.mesh_hash = proto_hex(r.bytes_copy(PROTO_MESH_HASH_SIZE));
    const count = r.u16();
    if (count > PROTO_OBJECT_BOXES_MAX)
        r.reject(S.BAD_VALUE);
    m.boxes = [];
    for (let i = 0; i < count && r.err === S.OK; i++) {
        const min = r.vec3(), max = [];
        for (let k = 0; k < 3; k++) {
            max.push(r.f32());
            if (!(min[k] <= max[k]))
                r.reject(S.BAD_VALUE);
        }
        m.boxes.push({ min, max });
    }
    return m;
}

/* The data runs to the end of the payload and lies within total. */
function decode_mesh_chunk(r) {
    const m = { object_id: r.id(), total: r.u32() };
    if (m.total === 0)
        r.reject(S.BAD_VALUE);
    m.offset = r.u32();
    if (m.offset >= m.total)
        r.reject(S.BAD_VALUE);
    const len = r.left;
    if (r.err === S.OK && (len === 0 || len > PROTO_MESH_CHUNK_MAX || len > m.total - m.offset))
        r.reject(len ? S.BAD_VALUE : S.SHORT);
    m.data = r.bytes_copy(len);
    return m;
}

function decode_collision(r) {
    const m = { object_id: r.id(), ecm_version: r.id(), box_index: r.u16(), inside: r.u8() };
    if (m.inside > 1)
        r.reject(S.BAD_VALUE);
    m.point = r.vec3();
    m.normal = r.vec3();
    return m;
}

/* An ERROR or OBJECT_REJECTED code: an error code, >= 16. */
function code(r) {
    const c = r.u16();
    if (c < S.FRAME_EMPTY)
        r.reject(S.BAD_VALUE);
    return c;
}

/* Decoders of the frames a server sends; the frames only a client sends
 * are UNEXPECTED from it, as section 8 says of the other direction. */
const DECODERS = {
    [T.WELCOME]: decode_welcome,
    [T.JOIN_OK]: decode_join_ok,
    [T.SNAPSHOT]: decode_snapshot,
    [T.AVATAR_JOINED]: (r) => ({ id: r.u32(), name: r.str(1, PROTO_NAME_MAX), pos: r.vec3(), box: r.box() }),
    [T.AVATAR_LEFT]: (r) => {
        const m = { id: r.u32(), reason: r.u8() };
        if (m.reason > 1)
            r.reject(S.BAD_VALUE);
        return m;
    },
    [T.ERROR]: (r) => ({ code: code(r), message: r.str(0, PROTO_MESSAGE_MAX) }),
    [T.PING]: (r) => ({ stamp: r.u64() }),
    [T.PONG]: (r) => ({ stamp: r.u64() }),
    [T.BYE]: (r) => {
        const m = { reason: r.u8() };
        if (m.reason > 2)
            r.reject(S.BAD_VALUE);
        return m;
    },
    [T.AVATAR_POSE]: (r) => ({ id: r.u32(), pose: r.pose() }),
    [T.OBJECT_INFO]: decode_object_info,
    [T.OBJECT_REMOVED]: (r) => ({ object_id: r.id() }),
    [T.OBJECT_REJECTED]: (r) => ({ request_id: r.u32(), code: code(r), message: r.str(0, PROTO_MESSAGE_MAX) }),
    [T.MESH_CHUNK]: decode_mesh_chunk,
    [T.COLLISION]: decode_collision,
};
const CLIENT_TYPES = new Set([T.HELLO, T.JOIN, T.MOVE, T.OBJECT_UPLOAD_BEGIN, T.OBJECT_UPLOAD_CHUNK,
    T.OBJECT_UPLOAD_END, T.OBJECT_PLACE, T.OBJECT_REMOVE, T.MESH_REQUEST]);

/*
 * Decodes one WebSocket message (an ArrayBuffer) as one frame from the
 * server. Returns {status: S.OK, type, m} with m the decoded fields
 * (strings as JS strings, hashes as hex, byte fields copied), or
 * {status, type} naming the first problem: the frame's own length must be
 * the message's (TRUNCATED otherwise), 2..PROTO_MAX_LEN (FRAME_EMPTY,
 * FRAME_TOO_LONG), then the payload as PROTOCOL.md, section 9.
 */
export function proto_decode(buf) {
    const bytes = new Uint8Array(buf);
    if (bytes.length < 4)
        return { status: S.TRUNCATED, type: 0 };
    const dv = new DataView(buf);
    const len = dv.getUint32(0, true);
    if (len < 2)
        return { status: S.FRAME_EMPTY, type: 0 };
    if (len > PROTO_MAX_LEN)
        return { status: S.FRAME_TOO_LONG, type: 0 };
    if (len !== bytes.length - 4)
        return { status: S.TRUNCATED, type: 0 };
    const type = dv.getUint16(4, true);
    const decode = DECODERS[type];
    if (!decode)
        return { status: CLIENT_TYPES.has(type) ? S.UNEXPECTED : S.UNKNOWN_TYPE, type };
    const r = new reader(bytes.subarray(PROTO_HEADER_SIZE));
    const m = decode(r);
    if (r.err === S.OK && r.left > 0)
        return { status: S.TRAILING, type };
    return r.err === S.OK ? { status: S.OK, type, m } : { status: r.err, type };
}

/* ---- encoding ---------------------------------------------------------- */

/* Appends fields to one frame; the frame's length is patched by end(). */
class writer {
    constructor(type, payload_max) {
        this.buf = new ArrayBuffer(PROTO_HEADER_SIZE + payload_max);
        this.dv = new DataView(this.buf);
        this.at = PROTO_HEADER_SIZE;
        this.dv.setUint16(4, type, true);
    }

    u8(v) { this.dv.setUint8(this.at, v); this.at += 1; }
    u16(v) { this.dv.setUint16(this.at, v, true); this.at += 2; }
    i16(v) { this.dv.setInt16(this.at, v, true); this.at += 2; }
    u32(v) { this.dv.setUint32(this.at, v, true); this.at += 4; }
    u64(v) { this.dv.setBigUint64(this.at, v, true); this.at += 8; }
    f32(v) { this.dv.setFloat32(this.at, v, true); this.at += 4; }
    vec3(v) { for (let i = 0; i < 3; i++) this.f32(v[i]); }

    bytes(b) {
        new Uint8Array(this.buf, this.at, b.length).set(b);
        this.at += b.length;
    }

    /* A u8 length and the bytes (already cut to their limit). */
    str(b) {
        this.u8(b.length);
        this.bytes(b);
    }

    pose(p) {
        this.f32(p.yaw);
        this.f32(p.pitch);
        this.u8(p.parts);
        for (let k = 0; k < PROTO_POSE_PARTS; k++) {
            if (!((p.parts >> k) & 1))
                continue;
            for (let i = 0; i < 3; i++)
                this.i16(p.pos[k][i]);
            for (let i = 0; i < 4; i++)
                this.i16(p.rot[k][i]);
        }
    }

    /* The whole frame, its length field set. */
    end() {
        this.dv.setUint32(0, this.at - 4, true);
        return this.buf.slice(0, this.at);
    }
}

export function proto_put_hello() {
    const w = new writer(T.HELLO, 6);
    w.u32(PROTO_MAGIC);
    w.u16(PROTO_VERSION);
    return w.end();
}

/* A join as a guest (password empty or absent) or with an account's
 * password (credential 1; its UTF-8 bytes, at most PROTO_PASSWORD_MAX:
 * the caller checks). The name must pass proto_name_problem. */
export function proto_put_join(name, box, password) {
    const n = proto_text_bytes(name, PROTO_NAME_MAX);
    const secret = password ? utf8_encoder.encode(password) : null;
    const w = new writer(T.JOIN, 1 + PROTO_NAME_MAX + 12 + 2 + PROTO_PASSWORD_MAX);
    w.str(n);
    w.vec3(box);
    if (secret) {
        w.u8(1);
        w.str(secret.subarray(0, PROTO_PASSWORD_MAX));
    }
    return w.end();
}

export function proto_password_bytes(password) {
    return utf8_encoder.encode(password).length;
}

/* A move to pos; with a pose (a quantized one: proto_pose_fit) when pose
 * is not null. */
export function proto_put_move(seq, pos, pose) {
    const w = new writer(T.MOVE, 16 + 9 + PROTO_POSE_PARTS * 14);
    w.u32(seq);
    w.vec3(pos);
    if (pose)
        w.pose(pose);
    return w.end();
}

function put_stamp(type, stamp) {
    const w = new writer(type, 8);
    w.u64(stamp);
    return w.end();
}

export function proto_put_ping(stamp) { return put_stamp(T.PING, stamp); }
export function proto_put_pong(stamp) { return put_stamp(T.PONG, stamp); }

export function proto_put_bye(reason) {
    const w = new writer(T.BYE, 1);
    w.u8(reason);
    return w.end();
}

/* name: a label (cut to PROTO_OBJECT_NAME_MAX bytes; the caller keeps it
 * within the text rule); format: [a-z0-9]{0,8}; up_axis 0 y, 1 z. */
export function proto_put_upload_begin(upload_id, total_size, name, format, up_axis, unit_scale) {
    const w = new writer(T.OBJECT_UPLOAD_BEGIN, 8 + 2 + PROTO_OBJECT_NAME_MAX + PROTO_FORMAT_MAX + 5);
    w.u32(upload_id);
    w.u32(total_size);
    w.str(proto_text_bytes(name, PROTO_OBJECT_NAME_MAX));
    w.str(proto_text_bytes(format, PROTO_FORMAT_MAX));
    w.u8(up_axis);
    w.f32(unit_scale);
    return w.end();
}

/* data: 1..PROTO_CHUNK_MAX bytes (a Uint8Array). */
export function proto_put_upload_chunk(upload_id, offset, data) {
    const w = new writer(T.OBJECT_UPLOAD_CHUNK, 8 + data.length);
    w.u32(upload_id);
    w.u32(offset);
    w.bytes(data);
    return w.end();
}

/* A frame of an id and a transform (section 1): OBJECT_UPLOAD_END and
 * OBJECT_PLACE. */
function put_transform(type, id, pos, yaw, scale) {
    const w = new writer(type, 24);
    w.u32(id);
    w.vec3(pos);
    w.f32(yaw);
    w.f32(scale);
    return w.end();
}

export function proto_put_upload_end(upload_id, pos, yaw, scale) {
    return put_transform(T.OBJECT_UPLOAD_END, upload_id, pos, yaw, scale);
}

export function proto_put_object_place(object_id, pos, yaw, scale) {
    return put_transform(T.OBJECT_PLACE, object_id, pos, yaw, scale);
}

/* hash: the 64 hex digits of OBJECT_INFO's mesh_hash. */
export function proto_put_mesh_request(object_id, hash) {
    const w = new writer(T.MESH_REQUEST, 4 + PROTO_MESH_HASH_SIZE);
    w.u32(object_id);
    for (let i = 0; i < PROTO_MESH_HASH_SIZE; i++)
        w.u8(parseInt(hash.substr(2 * i, 2), 16));
    return w.end();
}

/* ---- poses ------------------------------------------------------------- */

/* Rounds v x scale to the nearest int16, halves away from zero and
 * saturating, as proto.c's quantize; NaN gives 0. */
function quantize(v, scale) {
    const x = Math.sign(v * scale) * Math.round(Math.abs(v * scale));
    if (Number.isNaN(x))
        return 0;
    return Math.max(-32768, Math.min(32767, x));
}

/*
 * The pose a MOVE carries, quantized as proto_pose_set_part does: yaw and
 * pitch in radians (pitch clamped to +-PROTO_PITCH_MAX), and parts, an
 * object with any of head, left, right, each {p: [x, y, z] metres from
 * the avatar's position, q: [x, y, z, w]} (normalised here). A part the
 * server would refuse (a head out of range, a hand out of reach) is left
 * out, checked by the decoder itself, so a glitch of tracking never ends
 * the session: the hands go first, then the head.
 */
export function proto_pose_fit(yaw, pitch, parts) {
    const p = {
        yaw: Number.isFinite(yaw) ? yaw : 0,
        pitch: Number.isFinite(pitch) ? Math.max(-PROTO_PITCH_MAX, Math.min(PROTO_PITCH_MAX, pitch)) : 0,
        parts: 0, pos: [], rot: [],
    };
    const names = ['head', 'left', 'right'];
    for (let k = 0; k < PROTO_POSE_PARTS; k++) {
        const part = parts ? parts[names[k]] : null;
        p.pos.push([0, 0, 0]);
        p.rot.push([0, 0, 0, PROTO_QUAT_ONE]);
        if (!part)
            continue;
        const q = part.q, n = Math.hypot(q[0], q[1], q[2], q[3]);
        for (let i = 0; i < 3; i++)
            p.pos[k][i] = quantize(part.p[i], 1000);
        for (let i = 0; i < 4; i++)
            p.rot[k][i] = quantize(n > 0 ? q[i] / n : (i === 3 ? 1 : 0), PROTO_QUAT_ONE);
        p.parts |= 1 << k;
    }
    if (!(p.parts & 1))
        p.parts = 0;
    for (const mask of [p.parts, p.parts & 3, p.parts & 5, p.parts & 1, 0]) {
        const t = { ...p, parts: mask };
        const w = new writer(T.AVATAR_POSE, 9 + PROTO_POSE_PARTS * 14);
        w.pose(t);
        const r = new reader(new Uint8Array(w.end(), PROTO_HEADER_SIZE));
        r.pose();
        if (r.err === S.OK)
            return t;
    }
    return { ...p, parts: 0 };
}

/* A decoded pose in the units of cvre.state(): metres and unit
 * quaternions, null for a part that is not there. */
export function proto_pose_metres(p) {
    const part = (k) => ((p.parts >> k) & 1
        ? { p: p.pos[k].map((v) => v / 1000), q: p.rot[k].map((v) => v / PROTO_QUAT_ONE) }
        : null);
    return { yaw: p.yaw, pitch: p.pitch, head: part(0), left: part(1), right: part(2) };
}

/* ---- meshes ------------------------------------------------------------ */

/*
 * Checks bytes (a Uint8Array) as an encoded mesh, as proto_mesh_decode
 * does (counts, box, exact size, every index), and unpacks it. Returns
 * {status: S.OK, mesh: {vertex_count, tri_count, min, max, positions
 * (Float32Array, 3 a vertex, in the mesh's coordinates), indices
 * (Uint16Array or Uint32Array, 3 a triangle)}} or {status} naming the
 * problem.
 */
export function proto_mesh_decode(bytes) {
    if (bytes.length < PROTO_MESH_HEAD_SIZE)
        return { status: S.SHORT };
    const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    const v = dv.getUint32(0, true), t = dv.getUint32(4, true);
    if (v === 0 || t === 0 || t > PROTO_MESH_TRIS_MAX || v > 3 * t)
        return { status: S.BAD_VALUE };
    const min = [], max = [];
    for (let k = 0; k < 3; k++) {
        min.push(dv.getFloat32(8 + 4 * k, true));
        max.push(dv.getFloat32(20 + 4 * k, true));
        if (!Number.isFinite(min[k]) || !Number.isFinite(max[k]))
            return { status: S.NOT_FINITE };
        if (!(max[k] >= min[k]))
            return { status: S.BAD_VALUE };
    }
    const isz = v <= PROTO_MESH_SMALL_VERTS ? 2 : 4;
    const want = PROTO_MESH_HEAD_SIZE + 6 * v + isz * 3 * t;
    if (bytes.length < want)
        return { status: S.SHORT };
    if (bytes.length > want)
        return { status: S.TRAILING };
    const positions = new Float32Array(3 * v);
    const step = [0, 1, 2].map((k) => Math.fround(Math.fround(max[k] - min[k]) / PROTO_MESH_STEPS));
    for (let i = 0, at = PROTO_MESH_HEAD_SIZE; i < v; i++)
        for (let k = 0; k < 3; k++, at += 2)
            positions[3 * i + k] = min[k] + Math.fround(dv.getUint16(at, true) * step[k]);
    const indices = isz === 2 ? new Uint16Array(3 * t) : new Uint32Array(3 * t);
    for (let k = 0, at = PROTO_MESH_HEAD_SIZE + 6 * v; k < 3 * t; k++, at += isz) {
        indices[k] = isz === 2 ? dv.getUint16(at, true) : dv.getUint32(at, true);
        if (indices[k] >= v)
            return { status: S.BAD_VALUE };
    }
    return { status: S.OK, mesh: { vertex_count: v, tri_count: t, min, max, positions, indices } };
}
