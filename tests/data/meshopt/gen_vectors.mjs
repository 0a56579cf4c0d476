// Test vectors for shape_inversion/meshopt_codec.py: streams written by meshoptimizer's own encoder (npm
// `meshoptimizer`), expected output from its own decoder (MeshoptDecoder.decodeGltfBuffer).
import { MeshoptEncoder, MeshoptDecoder } from 'meshoptimizer';
import { createHash } from 'crypto';
await MeshoptEncoder.ready; await MeshoptDecoder.ready;
let seed = 12345;
const rnd = () => { seed = (seed * 1103515245 + 12345) & 0x7fffffff; return seed / 0x7fffffff; };
const hex = (a) => Buffer.from(a.buffer, a.byteOffset, a.byteLength).toString('hex');
const out = [];
function add(name, raw, count, size, mode, filter, version) {
  const enc = MeshoptEncoder.encodeGltfBuffer(raw, count, size, mode, version);
  const dec = new Uint8Array(count * size);
  MeshoptDecoder.decodeGltfBuffer(dec, count, size, enc, mode, filter);
  out.push({ name, count, byteStride: size, mode, filter, compressed: hex(enc), decoded_sha256: createHash('sha256').update(dec).digest('hex') });
}
// ATTRIBUTES: smooth and noisy data of several strides, codec versions 0 and 1, more than one 256-element block
for (const version of [0, 1]) for (const size of [4, 12, 16, 64]) {
  const count = size === 64 ? 140 : 260;  // past one block (256 elements; 128 of 64 bytes)
  const f = new Float32Array(count * size / 4);
  for (let i = 0; i < f.length; i++) f[i] = Math.sin(i * 0.01) * 10 + (i % 7 === 0 ? rnd() : 0);
  add(`attributes_v${version}_stride${size}`, new Uint8Array(f.buffer), count, size, 'ATTRIBUTES', 'NONE', version);
  const b = new Uint8Array(count * size);
  for (let i = 0; i < b.length; i++) b[i] = (i % size < 2) ? Math.floor(rnd() * 256) : (i >> 4) & 0xff;
  add(`attributes_v${version}_bytes${size}`, b, count, size, 'ATTRIBUTES', 'NONE', version);
}
// filters
const n = 100;
const norms = new Float32Array(n * 4), quats = new Float32Array(n * 4), cols = new Float32Array(n * 4), vals = new Float32Array(n * 3);
for (let i = 0; i < n; i++) {
  let x = rnd() - 0.5, y = rnd() - 0.5, z = rnd() - 0.5, l = Math.hypot(x, y, z);
  norms.set([x / l, y / l, z / l, 1], i * 4);
  let w = rnd() - 0.5; l = Math.hypot(x, y, z, w); quats.set([x / l, y / l, z / l, w / l], i * 4);
  cols.set([rnd(), rnd(), rnd(), rnd()], i * 4);
  vals.set([(rnd() - 0.5) * 1000, rnd() * 1e-3, rnd() * 5], i * 3);
}
for (const version of [0, 1]) {
  add(`oct8_v${version}`, MeshoptEncoder.encodeFilterOct(norms, n, 4, 8), n, 4, 'ATTRIBUTES', 'OCTAHEDRAL', version);
  add(`oct16_v${version}`, MeshoptEncoder.encodeFilterOct(norms, n, 8, 12), n, 8, 'ATTRIBUTES', 'OCTAHEDRAL', version);
  add(`quat_v${version}`, MeshoptEncoder.encodeFilterQuat(quats, n, 8, 12), n, 8, 'ATTRIBUTES', 'QUATERNION', version);
  add(`exp_v${version}`, MeshoptEncoder.encodeFilterExp(vals, n, 12, 15), n, 12, 'ATTRIBUTES', 'EXPONENTIAL', version);
  add(`exp_shared_v${version}`, MeshoptEncoder.encodeFilterExp(vals, n, 12, 10, 'SharedComponent'), n, 12, 'ATTRIBUTES', 'EXPONENTIAL', version);
  add(`color8_v${version}`, MeshoptEncoder.encodeFilterColor(cols, n, 4, 8), n, 4, 'ATTRIBUTES', 'COLOR', version);
  add(`color16_v${version}`, MeshoptEncoder.encodeFilterColor(cols, n, 8, 12), n, 8, 'ATTRIBUTES', 'COLOR', version);
}
// TRIANGLES (index codec versions 0 and 1) and INDICES: a grid mesh, with a few random triangles and resets
const tris = [];
const W = 12;
for (let r = 0; r < 10; r++) for (let c = 0; c < W - 1; c++) {
  const a = r * W + c; tris.push(a, a + 1, a + W, a + 1, a + W + 1, a + W);
}
for (let i = 0; i < 20; i++) tris.push(Math.floor(rnd() * 120), Math.floor(rnd() * 120) + 120, Math.floor(rnd() * 60000));
for (const size of [2, 4]) for (const version of [1]) {
  const idx = size === 2 ? new Uint16Array(tris) : new Uint32Array(tris);
  add(`triangles${size * 8}_v${version}`, new Uint8Array(idx.buffer), tris.length, size, 'TRIANGLES', 'NONE', version);
  add(`indices${size * 8}_v${version}`, new Uint8Array(idx.buffer), tris.length, size, 'INDICES', 'NONE', version);
}
console.log(JSON.stringify({ generator: 'meshoptimizer (npm) ' + process.env.MESHOPT_VERSION, vectors: out }));
