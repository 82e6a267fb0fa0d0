/*
 * web_proto.test.mjs: the web client's codec (client/web/src/proto.js)
 * against PROTOCOL.md: the worked examples byte for byte, the decoding
 * order of section 9 on the frames a client receives, the text rule, poses and the encoded mesh.
 * Run with `node --test tests/unit/web_proto.test.mjs` (Node 18 or later; no
 * browser); ctest runs it as web_proto.
 */
import { test } from 'node:test';
import assert from 'node:assert/strict';
import * as p from '../../client/web/src/proto.js';

const { S, T } = p;
const hex = (buf) => Buffer.from(buf).toString('hex');

/* A frame of type with payload bytes, as the server would send it. */
function frame(type, payload) {
    const b = new Uint8Array(6 + payload.length);
    const dv = new DataView(b.buffer);
    dv.setUint32(0, payload.length + 2, true);
    dv.setUint16(4, type, true);
    b.set(payload, 6);
    return b.buffer;
}

/* Little-endian payload builder. */
function bytes(...parts) {
    const out = [];
    for (const [kind, v] of parts) {
        const b = new DataView(new ArrayBuffer(8));
        if (kind === 'u8')
            out.push(v);
        else if (kind === 'u16') {
            b.setUint16(0, v, true);
            out.push(...new Uint8Array(b.buffer, 0, 2));
        } else if (kind === 'u32' || kind === 'bits') {
            b.setUint32(0, v, true);
            out.push(...new Uint8Array(b.buffer, 0, 4));
        } else if (kind === 'f32') {
            b.setFloat32(0, v, true);
            out.push(...new Uint8Array(b.buffer, 0, 4));
        } else if (kind === 'raw')
            out.push(...v);
    }
    return Uint8Array.from(out);
}

const NAN = 0x7fc00000;

test('worked examples of section 11, byte for byte', () => {
    assert.equal(hex(p.proto_put_hello()), '08000000010043565245' + '0200');
    assert.equal(hex(p.proto_put_move(1, [1, 0, -2.5], null)), '12000000050001000000' + '0000803f' + '00000000' + '000020c0');
    const pose = p.proto_pose_fit(0.5, -0.25, { head: { p: [0, 1.7, 0], q: [0, 0, 0, 1] } });
    assert.equal(hex(p.proto_put_move(2, [1, 0, -2.5], pose)),
        '29000000050002000000' + '0000803f00000000000020c0' + '0000003f000080be01' + '0000a4060000' + '000000000000ff7f');
    assert.equal(hex(p.proto_put_object_place(3, [0, 0, 10], Math.PI / 2, 2)),
        '1a000000230003000000' + '000000000000000000002041' + 'db0fc93f' + '00000040');
    assert.equal(hex(p.proto_put_upload_end(3, [0, 0, 10], Math.PI / 2, 2)).slice(8, 12), '2200');
});

test('framing: the message is exactly one frame within the cap', () => {
    const ok = frame(T.OBJECT_REMOVED, bytes(['u32', 7]));
    assert.equal(p.proto_decode(ok).status, S.OK);
    assert.equal(p.proto_decode(ok.slice(0, 9)).status, S.TRUNCATED);
    assert.equal(p.proto_decode(new Uint8Array(3).buffer).status, S.TRUNCATED);
    const empty = new Uint8Array(6);
    new DataView(empty.buffer).setUint32(0, 1, true);
    assert.equal(p.proto_decode(empty.buffer).status, S.FRAME_EMPTY);
    const long = new Uint8Array(6);
    new DataView(long.buffer).setUint32(0, p.PROTO_MAX_LEN + 1, true);
    assert.equal(p.proto_decode(long.buffer).status, S.FRAME_TOO_LONG);
});

test('types: reserved and unknown ones, and a client type from the server', () => {
    assert.equal(p.proto_decode(frame(36, new Uint8Array(0))).status, S.UNKNOWN_TYPE);
    assert.equal(p.proto_decode(frame(500, new Uint8Array(0))).status, S.UNKNOWN_TYPE);
    assert.equal(p.proto_decode(p.proto_put_hello()).status, S.UNEXPECTED);
});

test('decoding order: the first failure in field order wins', () => {
    /* A SNAPSHOT with a NaN in entry 0 and fewer entries than its count. */
    const snap = bytes(['u32', 1], ['u32', 0], ['u16', 2], ['u32', 5], ['bits', NAN], ['f32', 0], ['f32', 0]);
    assert.equal(p.proto_decode(frame(T.SNAPSHOT, snap)).status, S.NOT_FINITE);
    /* An OBJECT_INFO box whose min.x is above max.x and whose max.y is NaN. */
    const info = bytes(['u32', 3], ['u32', 0], ['u8', 1], ['raw', [0x77]], ['u8', 1], ['raw', [0x6f]],
        ['f32', 0], ['f32', 0], ['f32', 0], ['f32', 0], ['f32', 1], ['u32', 1], ['u32', 12],
        ['raw', new Array(32).fill(0xab)], ['u16', 1],
        ['f32', 2], ['f32', 0], ['f32', 0], ['f32', 1], ['bits', NAN], ['f32', 1]);
    assert.equal(p.proto_decode(frame(T.OBJECT_INFO, info)).status, S.BAD_VALUE);
    /* The same with a good box decodes, hash as hex. */
    const good = bytes(['u32', 3], ['u32', 9], ['u8', 1], ['raw', [0x77]], ['u8', 1], ['raw', [0x6f]],
        ['f32', 1], ['f32', 2], ['f32', 3], ['f32', 0.5], ['f32', 2], ['u32', 4], ['u32', 12],
        ['raw', new Array(32).fill(0xab)], ['u16', 1],
        ['f32', 0], ['f32', 0], ['f32', 0], ['f32', 1], ['f32', 1], ['f32', 1]);
    const d = p.proto_decode(frame(T.OBJECT_INFO, good));
    assert.equal(d.status, S.OK);
    assert.equal(d.m.mesh_hash, 'ab'.repeat(32));
    assert.deepEqual([d.m.upload_id, d.m.owner, d.m.name, d.m.at.scale, d.m.ecm_version], [9, 'w', 'o', 2, 4]);
    assert.equal(p.proto_decode(frame(T.OBJECT_INFO, Uint8Array.from([...good, 0]))).status, S.TRAILING);
    /* A scale out of range, a box count over the cap. */
    const small = Uint8Array.from(good);
    new DataView(small.buffer).setFloat32(28, 0.0001, true);
    assert.equal(p.proto_decode(frame(T.OBJECT_INFO, small)).status, S.BAD_VALUE);
});

test('the text rule for strings', () => {
    const err = (...text) => p.proto_decode(frame(T.ERROR, bytes(['u16', 40], ['u8', text.length], ['raw', text])));
    assert.equal(err(0x6f, 0x6b).m.message, 'ok');
    assert.equal(err(0xef, 0xbb, 0xbf).m.message, '\ufeff', 'a BOM is text');
    assert.equal(err(0xc0, 0x80).status, S.BAD_STRING, 'overlong');
    assert.equal(err(0xed, 0xa0, 0x80).status, S.BAD_STRING, 'surrogate');
    assert.equal(err(0xe2, 0x82).status, S.BAD_STRING, 'cut short');
    assert.equal(err(0x0a).status, S.BAD_STRING, 'line feed');
    assert.equal(err(0x7f).status, S.BAD_STRING, 'DEL');
    const over = p.proto_decode(frame(T.ERROR, bytes(['u16', 40], ['u8', 5], ['raw', [0x61]])));
    assert.equal(over.status, S.BAD_STRING, 'past the end');
    assert.equal(p.proto_decode(frame(T.ERROR, bytes(['u16', 15], ['u8', 0]))).status, S.BAD_VALUE, 'code below 16');
    const joined = bytes(['u32', 2], ['u8', 0], ['f32', 0], ['f32', 0], ['f32', 0], ['f32', 0.6], ['f32', 1.8], ['f32', 0.6]);
    assert.equal(p.proto_decode(frame(T.AVATAR_JOINED, joined)).status, S.BAD_STRING, 'an empty name');
});

test('welcome, join_ok and mesh chunks are checked for their ranges', () => {
    const welcome = (tick_hz, min_x, max_x) => bytes(['u16', 2], ['u32', 1], ['u32', 0], ['raw', new Array(16).fill(0)],
        ['u16', tick_hz], ['f32', 64], ['f32', 5], ['f32', min_x], ['f32', 0], ['f32', 0], ['f32', max_x], ['f32', 1], ['f32', 1],
        ['u32', 30000]);
    assert.equal(p.proto_decode(frame(T.WELCOME, welcome(20, -1, 1))).status, S.OK);
    assert.equal(p.proto_decode(frame(T.WELCOME, welcome(0, -1, 1))).status, S.BAD_VALUE);
    assert.equal(p.proto_decode(frame(T.WELCOME, welcome(20, 2, 1))).status, S.BAD_VALUE);
    const ok = bytes(['u32', 1], ['f32', 0], ['f32', 0], ['f32', 0], ['f32', 0.6], ['f32', 1.8], ['f32', 0.6]);
    assert.equal(p.proto_decode(frame(T.JOIN_OK, ok)).m.token, null);
    assert.equal(p.proto_decode(frame(T.JOIN_OK, Uint8Array.from([...ok, 1, 2]))).status, S.SHORT, 'a token cut short');
    const box = Uint8Array.from(ok);
    new DataView(box.buffer).setFloat32(16, 4.5, true);
    assert.equal(p.proto_decode(frame(T.JOIN_OK, box)).status, S.BAD_VALUE);
    const chunk = (total, offset, n) => frame(T.MESH_CHUNK, bytes(['u32', 4], ['u32', total], ['u32', offset], ['raw', new Array(n).fill(1)]));
    assert.equal(p.proto_decode(chunk(10, 2, 8)).status, S.OK);
    assert.equal(p.proto_decode(chunk(10, 2, 9)).status, S.BAD_VALUE, 'past total');
    assert.equal(p.proto_decode(chunk(10, 10, 1)).status, S.BAD_VALUE, 'offset at total');
    assert.equal(p.proto_decode(chunk(10, 2, 0)).status, S.SHORT, 'no data');
});

test('poses: decoded checks, and the fit that leaves out what the server would refuse', () => {
    const pose = (parts, ...rest) => frame(T.AVATAR_POSE, bytes(['u32', 9], ['f32', 0.1], ['f32', 0.2], ['u8', parts], ...rest));
    const unit = [['u16', 0], ['u16', 0], ['u16', 0], ['u16', 32767]];
    const d = p.proto_decode(pose(1, ['u16', 0], ['u16', 1700], ['u16', 0], ...unit));
    assert.equal(d.status, S.OK);
    assert.deepEqual(p.proto_pose_metres(d.m.pose).head, { p: [0, 1.7, 0], q: [0, 0, 0, 1] });
    assert.equal(p.proto_decode(pose(2)).status, S.BAD_VALUE, 'a hand without the head');
    assert.equal(p.proto_decode(pose(8)).status, S.BAD_VALUE, 'an unknown part');
    assert.equal(p.proto_decode(pose(1, ['u16', 4001], ['u16', 0], ['u16', 0], ...unit)).status, S.BAD_VALUE, 'head out of range');
    assert.equal(p.proto_decode(pose(1, ['u16', 0], ['u16', 0], ['u16', 0], ['u16', 0], ['u16', 0], ['u16', 0], ['u16', 20000])).status,
        S.BAD_VALUE, 'not a unit quaternion');
    const far = p.proto_pose_fit(0, 0, {
        head: { p: [0, 1.6, 0], q: [0, 0, 0, 1] },
        left: { p: [0, 1.6, 3], q: [0, 0, 0, 1] },
        right: { p: [0.3, 1.2, -0.2], q: [0, 0, 0, 2] },
    });
    assert.equal(far.parts, 5, 'the hand out of reach is left out');
    assert.deepEqual(far.rot[2], [0, 0, 0, 32767], 'normalised');
    assert.equal(p.proto_pose_fit(0, 0, { head: { p: [5, 0, 0], q: [0, 0, 0, 1] } }).parts, 0, 'a head out of range');
    assert.equal(p.proto_pose_fit(0, 9, null).pitch, p.PROTO_PITCH_MAX);
    assert.equal(p.proto_pose_fit(0, 0, { head: { p: [-0.0005, 0, 0], q: [0, 0, 0, 1] } }).pos[0][0], -1, 'halves away from zero');
});

test('the encoded mesh', () => {
    const mesh = (v, t, idx) => {
        const b = new Uint8Array(32 + 6 * v + 2 * idx.length);
        const dv = new DataView(b.buffer);
        dv.setUint32(0, v, true);
        dv.setUint32(4, t, true);
        for (let k = 0; k < 3; k++)
            dv.setFloat32(20 + 4 * k, 2, true);
        dv.setUint16(32 + 6, 65535, true);
        dv.setUint16(32 + 12 + 4, 65535, true);
        idx.forEach((x, i) => dv.setUint16(32 + 6 * v + 2 * i, x, true));
        return b;
    };
    const d = p.proto_mesh_decode(mesh(3, 1, [0, 1, 2]));
    assert.equal(d.status, S.OK);
    assert.deepEqual(Array.from(d.mesh.positions), [0, 0, 0, 2, 0, 0, 0, 0, 2]);
    assert.deepEqual(Array.from(d.mesh.indices), [0, 1, 2]);
    assert.equal(p.proto_mesh_decode(mesh(3, 1, [0, 1, 3])).status, S.BAD_VALUE, 'an index past the vertices');
    assert.equal(p.proto_mesh_decode(mesh(4, 1, [0, 1, 2])).status, S.BAD_VALUE, 'more than 3 vertices a triangle');
    assert.equal(p.proto_mesh_decode(mesh(3, 1, [0, 1])).status, S.SHORT);
    assert.equal(p.proto_mesh_decode(Uint8Array.from([...mesh(3, 1, [0, 1, 2]), 0])).status, S.TRAILING);
    const nan = mesh(3, 1, [0, 1, 2]);
    new DataView(nan.buffer).setUint32(8, NAN, true);
    assert.equal(p.proto_mesh_decode(nan).status, S.NOT_FINITE);
});

test('encoders: names cut at a character boundary, the mesh request hash', () => {
    assert.equal(p.proto_text_bytes('é'.repeat(40), 32).length, 32);
    assert.equal(p.proto_text_bytes('a' + 'é'.repeat(40), 32).length, 31);
    assert.equal(p.proto_name_problem(''), 'a name is needed');
    assert.match(p.proto_name_problem('x'.repeat(33)), /at most 32 bytes/);
    assert.equal(p.proto_name_problem('bob'), null);
    const req = new Uint8Array(p.proto_put_mesh_request(7, '0f'.repeat(32)));
    assert.equal(req.length, 6 + 36);
    assert.equal(hex(req.subarray(0, 10)), '26000000290007000000');
    assert.equal(req[41], 0x0f);
    const join = new Uint8Array(p.proto_put_join('bob', [0.6, 1.8, 0.6], 'pw'));
    assert.equal(hex(join.subarray(6)), '03626f62' + '9a99193f' + '6666e63f' + '9a99193f' + '01' + '02' + '7077');
});
