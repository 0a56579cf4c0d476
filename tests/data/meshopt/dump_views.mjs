// sha256 of every meshopt-compressed bufferView of a GLB, decoded by meshoptimizer's own decoder (npm `meshoptimizer`):
//   node dump_views.mjs file.glb ...  ->  {"file.glb": {"<view index>": "<sha256>", ...}, ...}
import { MeshoptDecoder } from 'meshoptimizer';
import { createHash } from 'crypto';
import fs from 'fs';
import path from 'path';
await MeshoptDecoder.ready;
const result = {};
for (const f of process.argv.slice(2)) {
  const d = fs.readFileSync(f);
  const jl = d.readUInt32LE(12);
  const j = JSON.parse(d.subarray(20, 20 + jl).toString());
  const bin = d.subarray(28 + jl, 28 + jl + d.readUInt32LE(20 + jl));
  const out = {};
  j.bufferViews.forEach((v, i) => {
    const e = (v.extensions || {}).EXT_meshopt_compression || (v.extensions || {}).KHR_meshopt_compression;
    if (!e) return;
    const src = bin.subarray(e.byteOffset || 0, (e.byteOffset || 0) + e.byteLength);
    const t = new Uint8Array(e.count * e.byteStride);
    MeshoptDecoder.decodeGltfBuffer(t, e.count, e.byteStride, src, e.mode, e.filter);
    out[i] = createHash('sha256').update(t).digest('hex');
  });
  result[path.basename(f)] = out;
}
console.log(JSON.stringify(result, null, 1));
