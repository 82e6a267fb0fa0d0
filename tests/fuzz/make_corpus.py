#!/usr/bin/env python3
"""Writes the seed corpora of the fuzz targets (tests/fuzz/README.md).

For each model target, the sample models of ../shared/models cut under
--max-file bytes (each file still a valid model), other encodings of them
(binary PLY of the ASCII one, ASCII STL of the binary one), and the hostile
inputs known: type confusion in a GLB's JSON, deep nesting, node cycles and
shared children, 2^31-1 STL triangles, 4e9 PLY vertices, 1e39 and 1e38
coordinates, indices out of range... For fuzz_proto, the seeds that
`fuzz_proto --write-seeds` writes plus hostile frames; for fuzz_http,
requests as clients send them and one of each class refused; for fuzz_ws,
client frames as browsers send them and one of each class refused, and
servers' answers to cvre-client --ws with their frames. Files named known-*
trigger bugs reported and not yet fixed (each target's known() skips them).

Deterministic: the same models make the same files. Existing files of the
same name are overwritten; others (crash files added by hand) are kept.

usage: make_corpus.py [--models DIR] [--out DIR] [--fuzz-proto BINARY]
"""
import argparse
import json
import os
import struct
import subprocess
import sys

MAX_FILE = 32 * 1024


def write(out, target, name, data):
    d = os.path.join(out, target)
    os.makedirs(d, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(d, name), 'wb') as f:
        f.write(data)


def copy_models(models, out, target, folder, ext):
    """Copies the sample models of one folder with the extension, whole."""
    for name in sorted(os.listdir(os.path.join(models, folder))):
        if name.endswith(ext):
            with open(os.path.join(models, folder, name), 'rb') as f:
                write(out, target, name, f.read())


# ---- GLB -----------------------------------------------------------------

def glb(doc, bin_=None, version=2, json_pad=b' '):
    j = doc if isinstance(doc, bytes) else json.dumps(doc, separators=(',', ':')).encode()
    j += json_pad * ((4 - len(j) % 4) % 4)
    body = struct.pack('<I', len(j)) + b'JSON' + j
    if bin_ is not None:
        b = bin_ + b'\0' * ((4 - len(bin_) % 4) % 4)
        body += struct.pack('<I', len(b)) + b'BIN\0' + b
    return b'glTF' + struct.pack('<II', version, 12 + len(body)) + body


def triangle_scene(positions=((0, 0, 0), (1, 0, 0), (0, 1, 0)), nodes=None, roots=(0,), extra=None):
    """A GLB of one triangle mesh; nodes and roots as given."""
    pos = b''.join(struct.pack('<3f', *p) for p in positions)
    doc = {'asset': {'version': '2.0'}, 'scene': 0,
           'buffers': [{'byteLength': len(pos)}],
           'bufferViews': [{'buffer': 0, 'byteOffset': 0, 'byteLength': len(pos)}],
           'accessors': [{'bufferView': 0, 'componentType': 5126, 'count': len(positions),
                          'type': 'VEC3'}],
           'meshes': [{'primitives': [{'attributes': {'POSITION': 0}}]}],
           'nodes': nodes if nodes is not None else [{'mesh': 0}],
           'scenes': [{'nodes': list(roots)}]}
    doc.update(extra or {})
    return doc, pos


def glb_corpus(models, out):
    t = 'fuzz_glb'
    copy_models(models, out, t, 'openings', '.glb')
    asset = {'asset': {'version': '2.0'}}
    # The shapes that overflowed the heap: an object where glTF has an array.
    write(out, t, 'accessors-object.glb', glb(dict(asset, accessors={'a': {'count': 5}})))
    write(out, t, 'accessors-object-of-array.glb', glb(dict(asset, accessors={'q': [1, 2]})))
    for key in ('nodes', 'meshes', 'scenes', 'bufferViews', 'buffers'):
        write(out, t, f'{key}-object.glb', glb(dict(asset, **{key: {'a': {}}})))
    doc, pos = triangle_scene()
    doc['meshes'][0]['primitives'] = {'a': {'attributes': {'POSITION': 0}}}
    write(out, t, 'primitives-object.glb', glb(doc, pos))
    doc, pos = triangle_scene(nodes=[{'mesh': 0, 'children': {'a': 0}}])
    write(out, t, 'children-object.glb', glb(doc, pos))
    doc, pos = triangle_scene()
    doc['meshes'][0]['primitives'][0]['attributes'] = [0]
    write(out, t, 'attributes-array.glb', glb(doc, pos))
    doc, pos = triangle_scene()
    doc['accessors'][0]['count'] = '3'
    write(out, t, 'count-string.glb', glb(doc, pos))
    # Nesting: past IMPORT_MAX_JSON_DEPTH (64), past jansson's own limit.
    for depth in (64, 65, 2049, 16000):
        text = b'{"asset":{"version":"2.0"},"extras":' + b'[' * depth + b']' * depth + b'}'
        write(out, t, f'nesting-{depth}.glb', glb(text))
    # Node graphs: cycles, a child listed twice, two parents, deep chains,
    # a root at every level of a chain.
    graphs = {
        'node-cycle': [{'mesh': 0, 'children': [1]}, {'children': [0]}],
        'node-self-child': [{'mesh': 0, 'children': [0]}],
        'node-child-twice': [{'children': [1, 1]}, {'mesh': 0}],
        'node-two-parents': [{'children': [2]}, {'children': [2]}, {'mesh': 0}],
        'node-child-out-of-range': [{'mesh': 0, 'children': [7]}],
        'node-child-negative': [{'mesh': 0, 'children': [-1]}],
        'node-mesh-out-of-range': [{'mesh': 5}],
    }
    for name, nodes in graphs.items():
        doc, pos = triangle_scene(nodes=nodes)
        write(out, t, name + '.glb', glb(doc, pos))
    doc, pos = triangle_scene(nodes=[{'mesh': 0}], roots=(0, 0))
    write(out, t, 'root-twice.glb', glb(doc, pos))
    doc, pos = triangle_scene(nodes=[{'children': [1]}, {'mesh': 0}], roots=(0, 1))
    write(out, t, 'root-and-child.glb', glb(doc, pos))
    for depth in (256, 257):
        nodes = [{'children': [i + 1]} for i in range(depth - 1)] + [{'mesh': 0}]
        doc, pos = triangle_scene(nodes=nodes)
        write(out, t, f'node-chain-{depth}.glb', glb(doc, pos))
    nodes = [{'children': [i + 1]} for i in range(449)] + [{'mesh': 0}]
    doc, pos = triangle_scene(nodes=nodes, roots=range(450))
    write(out, t, 'node-root-every-level.glb', glb(doc, pos))
    # Accessor elements copied once per primitive (the 17.6 GB file, small).
    doc, pos = triangle_scene()
    doc['meshes'][0]['primitives'] = [{'attributes': {'POSITION': 0}}] * 600
    write(out, t, 'accessor-shared-600.glb', glb(doc, pos))
    # Numbers: 1e38 (finite in float), past it, NaN, a huge scale.
    write(out, t, 'vertex-1e38.glb', glb(*triangle_scene(positions=((1e38, 0, 0), (1, 0, 0), (0, 1, 0)))))
    write(out, t, 'vertex-flt-max.glb',
          glb(*triangle_scene(positions=((3.4028235e38, -3.4028235e38, 0), (1, 0, 0), (0, 1, 0)))))
    pos = struct.pack('<3f', 0, 0, 0) + struct.pack('<3I', 0x7fc00000, 0x7f800000, 0xff800000) + \
        struct.pack('<3f', 0, 1, 0)
    doc, _ = triangle_scene()
    write(out, t, 'vertex-nan-inf.glb', glb(doc, pos))
    doc, pos = triangle_scene(nodes=[{'mesh': 0, 'scale': [1e38, 1e38, 1e38]}])
    write(out, t, 'node-scale-1e38.glb', glb(doc, pos))
    doc, pos = triangle_scene(nodes=[{'mesh': 0, 'matrix': [1e308] * 16}])
    write(out, t, 'node-matrix-1e308.glb', glb(doc, pos))
    # Counts, offsets and references out of range.
    for name, change in {
        'accessor-count-2e9': lambda d: d['accessors'][0].update(count=2147483647),
        'accessor-count-4e9': lambda d: d['accessors'][0].update(count=4294967295),
        'accessor-count-2e32': lambda d: d['accessors'][0].update(count=4294967296),
        'accessor-count-negative': lambda d: d['accessors'][0].update(count=-1),
        'accessor-count-real': lambda d: d['accessors'][0].update(count=3.5),
        'accessor-type-mat4': lambda d: d['accessors'][0].update(type='MAT4'),
        'accessor-component-int': lambda d: d['accessors'][0].update(componentType=5124),
        'accessor-view-out-of-range': lambda d: d['accessors'][0].update(bufferView=1),
        'view-length-huge': lambda d: d['bufferViews'][0].update(byteLength=4294967295),
        'view-offset-huge': lambda d: d['bufferViews'][0].update(byteOffset=2147483647),
        'view-stride-255': lambda d: d['bufferViews'][0].update(byteStride=255),
        'view-buffer-out-of-range': lambda d: d['bufferViews'][0].update(buffer=3),
        'buffer-length-huge': lambda d: d['buffers'][0].update(byteLength=4294967295),
        'buffer-uri-etc-passwd': lambda d: d['buffers'][0].update(uri='/etc/passwd'),
        'buffer-uri-data-bad': lambda d: d['buffers'][0].update(uri='data:application/octet-stream;base64,%%%'),
        'indices-out-of-range': lambda d: d['meshes'][0]['primitives'][0].update(indices=9),
        'mode-7': lambda d: d['meshes'][0]['primitives'][0].update(mode=7),
        'scene-out-of-range': lambda d: d.update(scene=4),
        'version-1': lambda d: d['asset'].update(version='1.0'),
        'version-number': lambda d: d['asset'].update(version=2),
        'draco': lambda d: d['meshes'][0]['primitives'][0].update(
            extensions={'KHR_draco_mesh_compression': {'bufferView': 0, 'attributes': {'POSITION': 0}}}),
    }.items():
        doc, pos = triangle_scene()
        change(doc)
        write(out, t, name + '.glb', glb(doc, pos))
    # The container: lengths that disagree, a NUL in the JSON, duplicate keys.
    doc, pos = triangle_scene()
    good = glb(doc, pos)
    write(out, t, 'container-version-1.glb', glb(doc, pos, version=1))
    write(out, t, 'container-length-short.glb', good[:8] + struct.pack('<I', len(good) - 4) + good[12:])
    write(out, t, 'container-json-length-huge.glb', good[:12] + struct.pack('<I', 0x7fffffff) + good[16:])
    write(out, t, 'container-truncated.glb', good[:len(good) - 7])
    write(out, t, 'container-bin-length-huge.glb',
          good[:-len(pos) - 8] + struct.pack('<I', 0xfffffff0) + good[-len(pos) - 4:])
    write(out, t, 'json-nul-padding.glb', glb(doc, pos, json_pad=b'\0'))
    text = json.dumps(doc, separators=(',', ':')).encode()
    write(out, t, 'json-nul-inside.glb', glb(text[:20] + b'\0' + text[21:], pos))
    write(out, t, 'json-duplicate-key.glb', glb(b'{"asset":{"version":"2.0"},' + text[1:], pos))
    # Reported, unfixed (fuzz_glb.c glb_known).
    doc, pos = triangle_scene()
    doc['meshes'][0]['primitives'] = [{'mode': 5}]
    write(out, t, 'known-strip-without-position-64gb.glb', glb(doc, pos))
    doc, pos = triangle_scene()
    doc['accessors'].append({'bufferView': 0, 'componentType': 5123, 'count': 18, 'type': 'SCALAR'})
    doc['meshes'][0]['primitives'] = [{'mode': 2, 'indices': 1}]
    write(out, t, 'known-line-loop-without-position-segv.glb', glb(doc, pos))
    doc, pos = triangle_scene()
    doc['accessors'][0]['byteOffset'] = 4
    write(out, t, 'known-accessor-offset-overread.glb', glb(doc, pos))
    doc, pos = triangle_scene()
    doc['bufferViews'].append({'buffer': 0, 'byteOffset': 36, 'byteLength': 4})
    doc['buffers'][0]['byteLength'] = 40
    doc['accessors'][0]['sparse'] = {'count': 1000, 'indices': {'bufferView': 1, 'componentType': 5123},
                                     'values': {'bufferView': 0}}
    write(out, t, 'known-sparse-count-overflow.glb', glb(doc, pos + struct.pack('<2H', 0, 1)))
    idx = struct.pack('<6H', 0, 1, 2, 0, 1, 2)
    doc, pos = triangle_scene()
    doc['buffers'][0]['byteLength'] = 48
    doc['bufferViews'].append({'buffer': 0, 'byteOffset': 36, 'byteLength': 12, 'byteStride': 4})
    doc['accessors'].append({'bufferView': 1, 'componentType': 5123, 'count': 6, 'type': 'SCALAR'})
    doc['meshes'][0]['primitives'][0]['indices'] = 1
    write(out, t, 'known-strided-indices-leak.glb', glb(doc, pos + idx))


# ---- OBJ -----------------------------------------------------------------

def cut_obj(text, max_bytes, max_vertices):
    """The first max_vertices v/vt/vn lines of each kind, the statements
    between them, and the faces that use only what was kept, until the file
    reaches max_bytes."""
    out, size, kept = [], 0, {'v': 0, 'vt': 0, 'vn': 0}
    for line in text.splitlines():
        words = line.split()
        if not words:
            continue
        kw = words[0]
        if kw in kept:
            if kept[kw] >= max_vertices:
                continue
            kept[kw] += 1
        elif kw in ('f', 'l', 'p'):
            ok = True
            for ref in words[1:]:
                for part, kind in zip(ref.split('/'), ('v', 'vt', 'vn')):
                    if part and (not part.lstrip('-').isdigit() or int(part) < 1 or int(part) > kept[kind]):
                        ok = False
            if not ok:
                continue
        if size + len(line) + 1 > max_bytes:
            break
        out.append(line)
        size += len(line) + 1
    return '\n'.join(out) + '\n'


def obj_corpus(models, out):
    t = 'fuzz_obj'
    for folder in ('openings', 'classic', 'scenes'):
        for name in sorted(os.listdir(os.path.join(models, folder))):
            if not name.endswith('.obj'):
                continue
            with open(os.path.join(models, folder, name), encoding='latin-1') as f:
                text = f.read()
            if len(text) > MAX_FILE:
                text = cut_obj(text, MAX_FILE - 1024, 400)
            write(out, t, name, text)
    tri = 'v 0 0 0\nv 1 0 0\nv 0 1 0\n'
    cases = {
        'coord-1e39.obj': 'v 1e39 0 0\nv 1 0 0\nv 0 1e39 0\nf 1 2 3\n',
        'coord-neg-1e39.obj': 'v -1e39 -1e39 -1e39\nv 1 0 0\nv 0 1 0\nf 1 2 3\n',
        'vertex-1e38.obj': 'v 1e38 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n',
        'vertex-flt-max.obj': 'v 3.4028235e38 0 0\nv 3.4028236e38 0 0\nv 0 1 0\nf 1 2 3\n',
        'vertex-nan.obj': 'v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n',
        'vertex-inf.obj': 'v inf -inf 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n',
        'vertex-1e309.obj': 'v 1e309 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n',
        'vertex-dot5.obj': 'v .5 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n',
        'vertex-two-numbers.obj': 'v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n',
        'face-index-0.obj': tri + 'f 0 1 2\n',
        'face-index-past-end.obj': tri + 'f 1 2 4\n',
        'face-index-before-first.obj': tri + 'f -4 -2 -1\n',
        'face-index-2e31.obj': tri + 'f 1 2 2147483648\n',
        'face-index-10-digits.obj': tri + 'f 1 2 0000000003\n',
        'face-texcoord-past-end.obj': tri + 'vt 0 0\nf 1/5 2/5 3/5\n',
        'face-normal-past-end.obj': tri + 'vn 0 0 1\nf 1//9 2//9 3//9\n',
        'face-four-parts.obj': tri + 'f 1/1/1/1 2 3\n',
        'face-before-vertices.obj': 'f 1 2 3\n' + tri,
        'polygon-10000.obj': tri + 'f' + ' 1 2 3' * 3333 + ' 1\n',
        'polygon-10001.obj': tri + 'f' + ' 1 2 3' * 3333 + ' 1 2\n',
        'groups-10001.obj': tri + 'f 1 2 3\n' + 'g\n' * 10001,
        'line-continuation.obj': 'v 0 0 \\\n0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n',
        'control-nul.obj': tri + 'f 1 2\0 3\n',
        'cr-line-ends.obj': tri.replace('\n', '\r') + 'f 1 2 3\r',
        'indented-vertex.obj': ' v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n',
        'mtllib-etc-passwd.obj': 'mtllib /etc/passwd\nusemtl root\n' + tri + 'f 1 2 3\n',
        'unknown-f-word.obj': tri + 'fo 1 2 3\nf 1 2 3\n',
        'known-line-texcoord-leak.obj': tri + 'vn 0 0 1\nf 1 2 3\ng g0\nl 1/1/1 2/1/1\n',
    }
    for name, text in cases.items():
        write(out, t, name, text)


# ---- PLY -----------------------------------------------------------------

def ply_parse(text):
    head, body = text.split('end_header\n', 1)
    return head + 'end_header\n', body.splitlines()


def ply_corpus(models, out):
    t = 'fuzz_ply'
    with open(os.path.join(models, 'formats', 'assimp_Wuson_ascii.ply'), encoding='latin-1') as f:
        head, lines = ply_parse(f.read())
    nv = int(head.split('element vertex ')[1].split()[0])
    verts, faces = lines[:nv], []
    keep = 120
    for line in lines[nv:]:
        w = line.split()
        if w and all(int(x) < keep for x in w[1:]):
            faces.append(line)
    head = head.replace(f'element vertex {nv}', f'element vertex {keep}')
    nf = int(head.split('element face ')[1].split()[0])
    head = head.replace(f'element face {nf}', f'element face {len(faces)}')
    write(out, t, 'assimp_Wuson_ascii-cut.ply', head + '\n'.join(verts[:keep] + faces) + '\n')
    # The same vertices and faces, binary, both byte orders.
    for order, fmt in (('<', 'binary_little_endian'), ('>', 'binary_big_endian')):
        body = b''.join(struct.pack(order + '8f', *map(float, v.split())) for v in verts[:keep])
        for line in faces:
            w = [int(x) for x in line.split()]
            body += struct.pack(order + 'B', w[0]) + struct.pack(order + f'{w[0]}I', *w[1:])
        write(out, t, f'assimp_Wuson_{fmt}-cut.ply', head.replace('format ascii', f'format {fmt}').encode() + body)

    def ascii_ply(nv, nf, verts, faces, vtype='float', ctype='uchar', itype='int', extra=''):
        return (f'ply\nformat ascii 1.0\n{extra}element vertex {nv}\nproperty {vtype} x\n'
                f'property {vtype} y\nproperty {vtype} z\nelement face {nf}\n'
                f'property list {ctype} {itype} vertex_indices\nend_header\n' + verts + faces)
    v3 = '0 0 0\n1 0 0\n0 1 0\n'
    f1 = '3 0 1 2\n'
    cases = {
        'vertices-4e9.ply': ascii_ply(4000000000, 1, v3, f1),
        'vertices-2e32-minus-1.ply': ascii_ply(4294967295, 1, v3, f1),
        'vertices-2e32.ply': ascii_ply(4294967296, 1, v3, f1),
        'vertices-negative.ply': ascii_ply(-1, 1, v3, f1),
        'faces-4e9.ply': ascii_ply(3, 4000000000, v3, f1),
        'vertex-1e38.ply': ascii_ply(3, 1, '1e38 0 0\n1 0 0\n0 1 0\n', f1),
        'vertex-1e39.ply': ascii_ply(3, 1, '1e39 0 0\n1 0 0\n0 1 0\n', f1),
        'vertex-nan.ply': ascii_ply(3, 1, 'nan 0 0\n1 0 0\n0 1 0\n', f1),
        'face-index-out-of-range.ply': ascii_ply(3, 1, v3, '3 0 1 7\n'),
        'face-index-negative.ply': ascii_ply(3, 1, v3, '3 0 1 -1\n'),
        'list-255-short.ply': ascii_ply(3, 1, v3, '255 0 1 2\n'),
        'list-count-float.ply': ascii_ply(3, 1, v3, '3 0 1 2\n', ctype='float'),
        'list-count-char-negative.ply': ascii_ply(3, 1, v3, '-3 0 1 2\n', ctype='char'),
        'list-items-float.ply': ascii_ply(3, 1, v3, '3 0.5 1 2\n', itype='float'),
        'vertex-type-uchar.ply': ascii_ply(3, 1, '0 0 0\n255 0 0\n0 255 0\n', f1, vtype='uchar'),
        'value-missing.ply': ascii_ply(3, 1, '0 0 0\n1 0\n0 1 0\n', f1),
        'value-extra.ply': ascii_ply(3, 1, '0 0 0 9\n1 0 0\n0 1 0\n', f1),
        'data-short.ply': ascii_ply(3, 2, v3, f1),
        'comment-obj-info.ply': ascii_ply(3, 1, v3, f1, extra='comment hi\nobj_info x\n'),
        'cr-in-header.ply': ascii_ply(3, 1, v3, f1).replace('format ascii 1.0\n', 'format ascii 1.0\r'),
        'no-end-header.ply': 'ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n',
        'property-before-element.ply': 'ply\nformat ascii 1.0\nproperty float x\nend_header\n',
        'element-no-properties.ply': 'ply\nformat ascii 1.0\nelement vertex 3\nend_header\n' + v3,
        'hostile-empty-face-abort.ply': ascii_ply(3, 1, v3, '0\n'),
        'known-quad-index-out-of-range-segv.ply': ascii_ply(4, 1, v3 + '0 0 1\n', '4 0 1 2 1000000000\n'),
        'hostile-vertex-list-negative-uchar-32gb.ply':
        'ply\nformat ascii 1.0\nelement vertex 3\nproperty uchar x\nproperty uchar y\n'
        'property list int16 uint8 p6\nend_header\n-1 2 3 7 5 7\n5 7 3 1 2 3\n6 1 3 5 1 3\n',
        'hostile-two-vertex-elements-heap-overflow.ply':
        'ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n'
        'element vertex 4\nproperty short x\nproperty short y\nelement face 1\n'
        'property list uchar int vertex_indices\nend_header\n' + v3 + '0 0\n1 0\n1 1\n0 1\n' + f1,
        'properties-257.ply': 'ply\nformat ascii 1.0\nelement vertex 1\n' +
        ''.join(f'property float p{i}\n' for i in range(257)) + 'end_header\n' + '0 ' * 257 + '\n',
    }
    for name, text in cases.items():
        write(out, t, name, text)
    bhead = ('ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\n'
             'property float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n')
    vb = struct.pack('<9f', 0, 0, 0, 1, 0, 0, 0, 1, 0)
    fb = struct.pack('<B3i', 3, 0, 1, 2)
    write(out, t, 'binary-vertices-4e9.ply', bhead.format(4000000000, 1).encode() + vb + fb)
    write(out, t, 'binary-vertex-1e38.ply', bhead.format(3, 1).encode() + struct.pack('<9f', 1e38, 0, 0, 1, 0, 0, 0, 1, 0) + fb)
    write(out, t, 'binary-vertex-nan.ply', bhead.format(3, 1).encode() + struct.pack('<I8f', 0x7fc00000, 0, 0, 1, 0, 0, 0, 1, 0) + fb)
    write(out, t, 'binary-list-255.ply', bhead.format(3, 1).encode() + vb + struct.pack('<B3i', 255, 0, 1, 2))
    write(out, t, 'binary-truncated.ply', bhead.format(3, 1).encode() + vb + fb[:6])


# ---- STL -----------------------------------------------------------------

def stl_binary(tris, count=None, header=b'fuzz_stl'):
    body = b''.join(struct.pack('<12fH', *([0.0, 0.0, 1.0] + list(t)), 0) for t in tris)
    return header.ljust(80, b' ') + struct.pack('<I', len(tris) if count is None else count) + body


def stl_ascii(tris, name='fuzz'):
    out = [f'solid {name}']
    for t in tris:
        out.append(' facet normal 0 0 1\n  outer loop')
        for k in range(3):
            out.append('   vertex {} {} {}'.format(*t[3 * k:3 * k + 3]))
        out.append('  endloop\n endfacet')
    out.append(f'endsolid {name}\n')
    return '\n'.join(out)


def stl_corpus(models, out):
    t = 'fuzz_stl'
    copy_models(models, out, t, 'openings', '.stl')
    with open(os.path.join(models, 'formats', 'assimp_Spider_binary.stl'), 'rb') as f:
        spider = f.read()
    n = (MAX_FILE - 1024 - 84) // 50
    write(out, t, 'assimp_Spider_binary-cut.stl', spider[:80] + struct.pack('<I', n) + spider[84:84 + 50 * n])
    tris = [struct.unpack('<9f', spider[84 + 50 * i + 12:84 + 50 * i + 48]) for i in range(40)]
    write(out, t, 'assimp_Spider-ascii-cut.stl', stl_ascii([['%g' % x for x in tr] for tr in tris], 'spider'))
    one = [(0, 0, 0, 1, 0, 0, 0, 1, 0)]
    nan = float('nan')
    cases = {
        'binary-count-2e31-minus-1.stl': stl_binary(one, count=2 ** 31 - 1),
        'binary-count-2e32-minus-1.stl': stl_binary(one, count=2 ** 32 - 1),
        'binary-count-0-with-data.stl': stl_binary(one, count=0),
        'binary-count-one-more.stl': stl_binary(one, count=2),
        'binary-header-solid.stl': stl_binary(one, header=b'solid fooled you'),
        'binary-vertex-1e38.stl': stl_binary([(1e38, 0, 0, 1, 0, 0, 0, 1e38, 0)]),
        'binary-vertex-flt-max.stl': stl_binary([(3.4028235e38, -3.4028235e38, 0, 1, 0, 0, 0, 1, 0)]),
        'binary-vertex-nan-inf.stl': stl_binary([(nan, float('inf'), float('-inf'), 1, 0, 0, 0, 1, 0)]),
        'binary-empty.stl': stl_binary([]),
        'binary-truncated.stl': stl_binary(one)[:100],
        'ascii-vertex-1e39.stl': stl_ascii([('1e39', 0, 0, 1, 0, 0, 0, 1, 0)]),
        'ascii-vertex-1e38.stl': stl_ascii([('1e38', 0, 0, 1, 0, 0, 0, 1, 0)]),
        'ascii-vertex-nan.stl': stl_ascii([('nan', 0, 0, 1, 0, 0, 0, 1, 0)]),
        'ascii-facet-cut.stl': stl_ascii([one[0]])[:60],
        'ascii-no-endloop.stl': stl_ascii([one[0]]).replace('  endloop\n', ''),
        'ascii-two-numbers.stl': stl_ascii([one[0]]).replace('vertex 1 0 0', 'vertex 1 0'),
        'ascii-number-next-line.stl': stl_ascii([one[0]]).replace('vertex 1 0 0', 'vertex\n1 0 0'),
        'ascii-solids-1000.stl': 'solid\nendsolid\n' * 1000,
        'ascii-control.stl': stl_ascii([one[0]]).replace('outer', 'out\0er', 1),
        'ascii-no-solid.stl': stl_ascii([one[0]]).replace('solid fuzz\n', '', 1),
    }
    for name, data in cases.items():
        write(out, t, name, data)


# ---- wire frames ---------------------------------------------------------

def frame(ftype, payload, length=None):
    return struct.pack('<IH', 2 + len(payload) if length is None else length, ftype) + payload


def proto_corpus(out, fuzz_proto):
    t = 'fuzz_proto'
    d = os.path.join(out, t)
    os.makedirs(d, exist_ok=True)
    if fuzz_proto:
        subprocess.run([fuzz_proto, '--write-seeds', d], check=True, stdout=subprocess.DEVNULL)
    hello = struct.pack('<IH', 0x45525643, 1)
    nan = struct.pack('<I', 0x7fc00000)
    # A pose (PROTOCOL.md 6.5): facing, then head and both hands in mm and
    # quaternions x 32767.
    pose = struct.pack('<ffB', 0.5, -0.25, 7) + b''.join(
        struct.pack('<3h4h', *at, 0, 0, 0, 32767) for at in ((0, 1700, 0), (-300, 1200, 400), (300, 1200, 400)))
    cases = {
        'hostile-length-0': struct.pack('<I', 0) + b'\1\0',
        'hostile-length-1': struct.pack('<I', 1) + b'\1',
        'hostile-length-ffffffff': frame(1, hello, 0xffffffff),
        'hostile-length-prejoin-plus-1': frame(3, b'\0' * 127),
        'hostile-length-max-plus-1': struct.pack('<IH', 65537, 33) + b'\0' * 64,
        'hostile-length-short-by-one': frame(1, hello, 7),
        'hostile-header-cut': struct.pack('<I', 8)[:3],
        'hostile-type-unknown': frame(0xffff, b''),
        'hostile-type-reserved': frame(36, b'\0' * 8),
        'hostile-type-zero': frame(0, b''),
        'hostile-hello-bad-magic': frame(1, struct.pack('<IH', 0xdeadbeef, 1)),
        'hostile-hello-trailing': frame(1, hello + b'x'),
        'hostile-move-nan': frame(5, struct.pack('<I', 1) + nan * 3),
        'hostile-move-inf': frame(5, struct.pack('<I3I', 1, 0x7f800000, 0xff800000, 0)),
        'move-pose-full': frame(5, struct.pack('<I3f', 1, 0, 0, 0) + pose),
        'avatar-pose-head': frame(13, struct.pack('<I', 7) + pose[:8] + b'\1' + pose[9:9 + 14]),
        'hostile-pose-yaw-nan': frame(5, struct.pack('<I3f', 1, 0, 0, 0) + nan + pose[4:]),
        'hostile-pose-pitch-over': frame(13, struct.pack('<Iff', 7, 0, 1.6) + b'\0'),
        'hostile-pose-hands-no-head': frame(13, struct.pack('<I', 7) + pose[:8] + b'\6' + pose[9 + 14:]),
        'hostile-pose-quat-zero': frame(13, struct.pack('<I', 7) + pose[:9 + 6] + b'\0' * 8),
        'hostile-pose-hand-far': frame(5, struct.pack('<I3f', 1, 0, 0, 0) + pose[:9 + 14] +
                                       struct.pack('<3h4h', 0, 1700, 1600, 0, 0, 0, 32767) + pose[9 + 28:]),
        'hostile-pose-parts-high': frame(13, struct.pack('<Iff', 7, 0, 0) + b'\x80'),
        'hostile-pose-cut': frame(13, struct.pack('<I', 7) + pose[:20]),
        'hostile-join-bad-utf8': frame(3, bytes([3]) + b'\xc3\x28\xff' + struct.pack('<3f', 1, 1, 1)),
        'hostile-join-name-past-end': frame(3, bytes([200]) + b'ab'),
        'hostile-snapshot-count-over': frame(6, struct.pack('<IIH', 1, 1, 60000)),
        'hostile-object-info-boxes-over': frame(38, b'\0' * 70 + struct.pack('<H', 1025)),
        'hostile-chunk-empty': frame(33, struct.pack('<II', 1, 0)),
        'hostile-chunk-over': frame(33, struct.pack('<II', 1, 0) + b'\0' * 16385),
        'hostile-upload-begin-scale-nan': frame(32, struct.pack('<II', 1, 10) + b'\1a\3obj\0' + nan),
        'hostile-two-frames-second-cut': frame(10, b'\0' * 8) + frame(10, b'\0' * 8)[:9],
        'hostile-ping-then-garbage': frame(10, b'\0' * 8) + b'\xff' * 16,
        # Meshes (PROTOCOL.md 6.22, 6.23): a request for id 0 or cut short; a
        # chunk with no data, starting at its total, running past it, over the cap.
        'hostile-mesh-request-id-zero': frame(41, b'\0' * 36),
        'hostile-mesh-request-cut': frame(41, struct.pack('<I', 1) + b'\xab' * 20),
        'hostile-mesh-chunk-empty': frame(42, struct.pack('<III', 1, 10, 0)),
        'hostile-mesh-chunk-at-total': frame(42, struct.pack('<III', 1, 10, 10) + b'x'),
        'hostile-mesh-chunk-past-total': frame(42, struct.pack('<III', 1, 10, 5) + b'x' * 6),
        'hostile-mesh-chunk-over': frame(42, struct.pack('<III', 1, 0xffffffff, 0) + b'\0' * 16385),
    }
    for name, data in cases.items():
        write(out, t, name, data)


# ---- HTTP request heads ------------------------------------------------------

HTTP_HEAD_MAX, HTTP_URL_MAX, HTTP_HEADERS_MAX = 8192, 2048, 32  # server/net/http.h


def http_corpus(out):
    """Requests as scrapers, curl and browsers send them, and each class
    server/net/http.c refuses, at and past every limit."""
    def head(line, *headers, eol='\r\n'):
        return eol.join((line,) + headers) + eol + eol

    def filled(total):
        start = 'GET /metrics HTTP/1.1\r\nHost: h\r\nX-Fill: '
        return start + 'f' * (total - len(start) - 4) + '\r\n\r\n'

    seeds = {
        'prometheus': head('GET /metrics HTTP/1.1', 'Host: 127.0.0.1:9100', 'User-Agent: Prometheus/2.45.0',
                           'Accept: application/openmetrics-text;version=1.0.0,text/plain;version=0.0.4;q=0.5',
                           'Accept-Encoding: gzip', 'X-Prometheus-Scrape-Timeout-Seconds: 10'),
        'curl': head('GET /metrics HTTP/1.1', 'Host: localhost:9100', 'User-Agent: curl/7.88.1', 'Accept: */*'),
        'http10': head('GET /metrics HTTP/1.0'),
        'absolute': head('GET http://h:9100/metrics?name[]=x HTTP/1.1', 'Host: h:9100'),
        'options-star': head('OPTIONS * HTTP/1.1', 'Host: h'),
        'connect': head('CONNECT h:443 HTTP/1.1', 'Host: h:443'),
        'websocket': head('GET /ws HTTP/1.1', 'Host: h', 'Upgrade: websocket', 'Connection: Upgrade',
                          'Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==', 'Sec-WebSocket-Version: 13'),
        'folded': head('GET / HTTP/1.1', 'Host: h', 'X-Long: first', ' second'),
        'lf-only': head('GET / HTTP/1.1', 'Host: h', eol='\n'),
        'pipelined': head('GET /a HTTP/1.1', 'Host: h') + head('GET /b HTTP/1.1', 'Host: h'),
        'no-host': head('GET / HTTP/1.1'),
        'no-colon': head('GET / HTTP/1.1', 'Host: h', 'No colon'),
        'nul': head('GET / HTTP/1.1', 'Host: h\0x'),
        'version-2': head('GET / HTTP/2.0', 'Host: h'),
        'body': head('POST /metrics HTTP/1.1', 'Host: h', 'Content-Length: 5') + 'hello',
        'chunked': head('POST /metrics HTTP/1.1', 'Host: h', 'Transfer-Encoding: chunked') + '5\r\nhello\r\n0\r\n\r\n',
        'two-lengths': head('GET / HTTP/1.1', 'Host: h', 'Content-Length: 0', 'Content-Length: 1'),
        'head-at-cap': filled(HTTP_HEAD_MAX),
        'head-past-cap': filled(HTTP_HEAD_MAX + 1),
        'target-at-cap': head('GET /' + 'u' * (HTTP_URL_MAX - 1) + ' HTTP/1.1', 'Host: h'),
        'target-past-cap': head('GET /' + 'u' * HTTP_URL_MAX + ' HTTP/1.1', 'Host: h'),
        'headers-at-cap': head('GET / HTTP/1.1', 'Host: h', *[f'X-{i}: {i}' for i in range(1, HTTP_HEADERS_MAX)]),
        'headers-past-cap': head('GET / HTTP/1.1', 'Host: h', *[f'X-{i}: {i}' for i in range(1, HTTP_HEADERS_MAX + 1)]),
        'unfinished': 'GET /metrics HTTP/1.1\r\nHost: h\r\n',
    }
    for name, text in seeds.items():
        write(out, 'fuzz_http', name, text)


WS_CAP = 3000  # tests/fuzz/fuzz_ws.c's FUZZ_WS_CAP


def ws_frame(b0, payload=b'', form=None, masked=True, length=None):
    """A client frame: first byte b0, the payload masked with a fixed key,
    its length (or `length`) in form bytes (1, 2 or 8; None: the shortest)."""
    n = len(payload) if length is None else length
    form = form or (1 if n < 126 else 2 if n <= 0xFFFF else 8)
    m = 0x80 if masked else 0
    head = bytes([b0])
    if form == 1:
        head += bytes([m | n])
    elif form == 2:
        head += bytes([m | 126]) + struct.pack('>H', n)
    else:
        head += bytes([m | 127]) + struct.pack('>Q', n)
    if not masked:
        return head + payload
    key = b'\x37\xfa\x21\x3d'
    return head + key + bytes(c ^ key[i % 4] for i, c in enumerate(payload))


# The answer to fuzz_ws.c's FUZZ_WS_KEY (RFC 6455's example), as the server writes it.
WS_ANSWER = (b'HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n'
             b'Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\n\r\n')


def ws_corpus(out):
    """WebSocket client frames (fuzz_ws): what browsers send, and one of
    each class protocol/ws.c refuses; and a server's answers and frames
    as cvre-client --ws reads them."""
    FIN, BIN, CONT, TEXT, CLOSE, PING, PONG = 0x80, 0x2, 0x0, 0x1, 0x8, 0x9, 0xA
    proto = frame(3, bytes([4]) + b'anna' + struct.pack('<3f', 1, 1, 1))  # a JOIN, as one message
    seeds = {
        'binary-proto-frame': ws_frame(FIN | BIN, proto),
        'binary-empty': ws_frame(FIN | BIN),
        'binary-16bit': ws_frame(FIN | BIN, bytes(range(256)) * 2),
        'binary-at-cap': ws_frame(FIN | BIN, b'\x01' * WS_CAP),
        'fragments-with-controls': ws_frame(BIN, b'a' * 100) + ws_frame(FIN | PING, b'p') +
        ws_frame(CONT, b'b' * 100) + ws_frame(FIN | PONG) + ws_frame(FIN | CONT, b'c' * 100),
        'ping-pong': ws_frame(FIN | PING, b'x' * 125) + ws_frame(FIN | PONG, b'y'),
        'close-empty': ws_frame(FIN | CLOSE),
        'close-reason': ws_frame(FIN | CLOSE, struct.pack('>H', 1000) + 'fin \u00e9'.encode()),
        'close-4999': ws_frame(FIN | CLOSE, struct.pack('>H', 4999)),
        'bad-close-1005': ws_frame(FIN | CLOSE, struct.pack('>H', 1005)),
        'bad-close-one-byte': ws_frame(FIN | CLOSE, b'\x03'),
        'bad-close-utf8': ws_frame(FIN | CLOSE, struct.pack('>H', 1000) + b'\xc3'),
        'bad-unmasked': ws_frame(FIN | BIN, proto, masked=False),
        'bad-rsv1': ws_frame(FIN | 0x40 | BIN, proto),
        'bad-opcode-3': ws_frame(FIN | 0x3, b'x'),
        'bad-opcode-b': ws_frame(FIN | 0xB, b'x'),
        'bad-text': ws_frame(FIN | TEXT, b'hello'),
        'bad-length-top-bit': ws_frame(FIN | BIN, form=8, length=1 << 63),
        'bad-length-not-shortest': ws_frame(FIN | BIN, b'abc', form=2),
        'bad-ping-fragmented': ws_frame(PING, b'x'),
        'bad-ping-126': ws_frame(FIN | PING, b'x' * 126),
        'bad-continuation-alone': ws_frame(FIN | CONT, b'x'),
        'bad-message-in-message': ws_frame(BIN, b'x') + ws_frame(FIN | BIN, b'y'),
        'too-big': ws_frame(FIN | BIN, form=8, length=1 << 40),
        'too-big-fragments': ws_frame(BIN, b'a' * 2000) + ws_frame(FIN | CONT, b'b' * 1001),
        'unfinished': ws_frame(FIN | BIN, proto)[:-3],
        'server-answer-and-frames': WS_ANSWER + ws_frame(FIN | BIN, proto, masked=False) +
        ws_frame(FIN | PING, b'p', masked=False) + ws_frame(FIN | CLOSE, struct.pack('>H', 1013) + b'full',
                                                           masked=False),
        'server-answer-cut': WS_ANSWER[:-3],
        'server-refusal-426': b'HTTP/1.1 426 Upgrade Required\r\nSec-WebSocket-Version: 13\r\n\r\n',
        'server-wrong-accept': WS_ANSWER.replace(b's3pP', b'AAAA') + ws_frame(FIN | BIN, proto, masked=False),
        'server-bad-masked': WS_ANSWER + ws_frame(FIN | BIN, proto),
    }
    for name, data in seeds.items():
        write(out, 'fuzz_ws', name, data)


# ---- web root request targets ----------------------------------------------

WEB_FILES_PATH_MAX = 1024  # server/net/web_files.h


def web_files_corpus(out):
    """Request targets (fuzz_web_files) against the root of tests/webroot.h:
    what the browser client asks for, and each way server/net/web_files.c
    refuses to leave the root, at and past the path limit."""
    seeds = {
        'index': '/',
        'index-with-query': '/?name=ann',
        'script': '/app.js?v=3',
        'module': '/mod.mjs#top',
        'deep': '/sub/deeper/model.glb',
        'sub-index': '/sub/',
        'escaped-space': '/with%20space.txt',
        'escaped-percent': '/100%25.txt',
        'escaped-utf8': '/%C3%A9t%c3%a9.txt',
        'decoded-once': '/%2561pp.js',
        'directory': '/sub',
        'missing': '/sub/missing.js',
        'fifo': '/fifo',
        'hidden': '/.git/config',
        'dotdot': '/../outside.txt',
        'dotdot-inside': '/sub/../app.js',
        'dotdot-encoded': '/%2e%2e/outside.txt',
        'dotdot-mixed-case': '/%2E%2e/outside-dir/secret.txt',
        'dotdot-half-encoded': '/.%2E/outside.txt',
        'dot': '/./app.js',
        'empty-segment': '//etc/passwd',
        'backslash': '/..\\outside.txt',
        'backslash-encoded': '/%5c..%5coutside.txt',
        'slash-encoded': '/sub%2findex.html',
        'nul-encoded': '/app.js%00.png',
        'nul-raw': '/app.js\0.png',
        'newline-encoded': '/a%0d%0ab',
        'bad-escape': '/%zz',
        'cut-escape': '/app.js%2',
        'symlink-in': '/link-in',
        'symlink-dir-in': '/link-dir-in/index.html',
        'symlink-out': '/link-out',
        'symlink-dir-out': '/link-dir-out/secret.txt',
        'symlink-absolute': '/link-abs',
        'symlink-up': '/sub/link-up/outside.txt',
        'absolute-form': 'http://h/app.js',
        'asterisk': '*',
        'path-at-cap': '/' + 'p' * (WEB_FILES_PATH_MAX - 1),
        'path-past-cap': '/' + 'p' * WEB_FILES_PATH_MAX,
        'long-query': '/app.js?' + 'q' * 1500,
    }
    for name, text in seeds.items():
        write(out, 'fuzz_web_files', name, text)


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--models', default=os.path.join(here, '..', '..', '..', 'shared', 'models'))
    p.add_argument('--out', default=os.path.join(here, 'corpus'))
    p.add_argument('--fuzz-proto', help='a built fuzz_proto, for its --write-seeds')
    a = p.parse_args()
    glb_corpus(a.models, a.out)
    obj_corpus(a.models, a.out)
    ply_corpus(a.models, a.out)
    stl_corpus(a.models, a.out)
    proto_corpus(a.out, a.fuzz_proto)
    http_corpus(a.out)
    ws_corpus(a.out)
    web_files_corpus(a.out)
    total = 0
    for t in sorted(os.listdir(a.out)):
        files = os.listdir(os.path.join(a.out, t))
        size = sum(os.path.getsize(os.path.join(a.out, t, f)) for f in files)
        big = max(os.path.getsize(os.path.join(a.out, t, f)) for f in files)
        total += size
        print(f'{t}: {len(files)} files, {size} bytes, largest {big}')
    print(f'total {total} bytes')


if __name__ == '__main__':
    sys.exit(main())
