// Loads a bake directory with js/homofac-three.js's loadBake (under node, no WebGL: the textures are built, not
// uploaded) and prints, per texture uniform, what three would upload: size, type, reader and the texels
// (base64 of the typed array). Usage: node load-bake-info.mjs http://host/bake/
import { loadBake } from './homofac-three.js';

// three's FileLoader (used by EXRLoader) reports progress with the browser's ProgressEvent, which node lacks.
globalThis.ProgressEvent ??= class ProgressEvent extends Event {
  constructor(type, init = {}) { super(type); Object.assign(this, { lengthComputable: false, loaded: 0, total: 0, ...init }); }
};

const bake = await loadBake(process.argv[2]);
const out = { lookups: bake.lookups, textures: {} };
for (const [name, t] of Object.entries(bake.textures)) {
  const { width, height, data } = t.image;
  const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  out.textures[name] = { width, height, type: t.type, flipY: t.flipY, source: bake.sources[name],
    channels: data.length / (width * height), data: Buffer.from(bytes).toString('base64') };
}
process.stdout.write(JSON.stringify(out));
