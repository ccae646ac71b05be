// homofac for three.js: MeshStandardMaterial (and MeshPhysicalMaterial's base layer) take their image-based
// lighting from a homofac bake instead of PMREM.
//
//   import { loadBake, applyBake } from './homofac-three.js';
//   const bake = await loadBake('bake/');               // a directory written by `python -m homofac.bake`
//   gltf.scene.traverse((o) => { if (o.isMesh) applyBake(o.material, bake); });
//
// A bake written with --ktx2 can be read by three's own KTX2Loader:
//   loadBake('bake/', { ktx2Loader: new KTX2Loader().detectSupport(renderer) })
//
// The bake holds three integrals of the environment, I_d(n, v), I_A(n, v, rho), I_B(n, v, rho) (docs/format.md,
// "The bake directory"); with the material's own base colour c, metallic m and roughness rho the outgoing
// radiance is (1 - m) 0.96 c I_d + f0 I_A + I_B with f0 = mix(0.04, c, m): the glTF 2.0 BRDF, exact in c and m.
// applyBake adds that to three's indirect diffuse and specular, after its texture reads (maps, normal maps)
// and before its ambient-occlusion chunk, so aoMap, lights and everything else in the material keep working.
// The bake's generated GLSL ES function homofac_ibl_terms (its shader_es.glsl) is compiled into the
// material with HOMOFAC_Y_UP: three's y-up world frame maps to homofac's +z-up one. It also adds the bake's
// analytic sources (bake.json `sources`: the brightest compact source, taken out of the maps) with the
// glTF lobes widened by each source's radius, from constants, so nothing here reads them.

import {
  DataTexture, EquirectangularReflectionMapping, FloatType, HalfFloatType, LinearFilter, ClampToEdgeWrapping, LinearSRGBColorSpace, RGBAFormat,
} from 'three';
import { EXRLoader } from 'three/addons/loaders/EXRLoader.js';
import { read as readKTX2 } from 'three/addons/libs/ktx-parse.module.js';

const FORMAT = 'homofac.bake';
// The only names a bake directory holds (docs/format.md): nothing in bake.json can point elsewhere.
const TEXTURE_NAME = /^[PEW][0-9]{1,2}$/;
const TEXTURE_FILE = /^[PEW][0-9]{1,2}\.(exr|ktx2)$/;
const SHADER_FILE = 'shader_es.glsl';
// VkFormat values of the uncompressed RGBA textures a bake's KTX2 files use.
const VK_R16G16B16A16_SFLOAT = 97;
const VK_R32G32B32A32_SFLOAT = 109;

function joinUrl(base, file) {
  const dir = new URL(base.endsWith('/') ? base : `${base}/`, globalThis.location ? globalThis.location.href : undefined);
  return new URL(file, dir).href;
}

async function fetchOk(url, kind) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`homofac: ${url}: HTTP ${r.status}`);
  return kind === 'json' ? r.json() : kind === 'text' ? r.text() : r.arrayBuffer();
}

function finish(texture) {
  texture.magFilter = LinearFilter;
  texture.minFilter = LinearFilter;
  texture.wrapS = ClampToEdgeWrapping;
  texture.wrapT = ClampToEdgeWrapping;
  texture.generateMipmaps = false;
  texture.flipY = false; // rows in file order: row 0 at v = 0, as homofac's shaders read them
  texture.colorSpace = LinearSRGBColorSpace;
  texture.needsUpdate = true;
  return texture;
}

// A 2D KTX2 file (one level, one layer) of RGBA half or float texels as a DataTexture.
function ktx2Texture(buffer, url) {
  const c = readKTX2(new Uint8Array(buffer));
  const level = c.levels[0].levelData;
  let data;
  let type;
  if (c.vkFormat === VK_R16G16B16A16_SFLOAT) {
    data = new Uint16Array(level.buffer, level.byteOffset, level.byteLength / 2);
    type = HalfFloatType;
  } else if (c.vkFormat === VK_R32G32B32A32_SFLOAT) {
    data = new Float32Array(level.buffer, level.byteOffset, level.byteLength / 4);
    type = FloatType;
  } else {
    throw new Error(`homofac: ${url}: VkFormat ${c.vkFormat} is not an RGBA half or float format`);
  }
  if (c.pixelDepth > 1 || c.layerCount > 1 || c.faceCount !== 1) {
    throw new Error(`homofac: ${url}: a bake's textures are 2D (got depth ${c.pixelDepth}, layers ${c.layerCount}, faces ${c.faceCount})`);
  }
  return finish(new DataTexture(data, c.pixelWidth, c.pixelHeight, RGBAFormat, type));
}

// A 2D KTX2 file read by three's own KTX2Loader (the engine's loader, as for any other KTX2 asset).
async function ktx2LoaderTexture(loader, url) {
  const tex = await loader.loadAsync(url);
  if (!tex.isDataTexture || tex.isData3DTexture || tex.format !== RGBAFormat || !(tex.type === HalfFloatType || tex.type === FloatType)) {
    throw new Error(`homofac: ${url}: KTX2Loader did not give a 2D RGBA half or float texture`);
  }
  tex.mipmaps = [];
  return finish(tex);
}

async function loadTexture(base, entry, ktx2Loader) {
  if (entry.ktx2) {
    const url = joinUrl(base, entry.ktx2);
    if (ktx2Loader) return [await ktx2LoaderTexture(ktx2Loader, url), 'KTX2Loader'];
    return [ktx2Texture(await fetchOk(url, 'buffer'), url), 'ktx-parse'];
  }
  const url = joinUrl(base, entry.file);
  const tex = await new EXRLoader().setDataType(HalfFloatType).loadAsync(url);
  // EXRLoader puts the file's last row first (v = 0 at the image's bottom); a bake reads rows in file order
  const { width: w, height: h, data } = tex.image;
  const c = data.length / (w * h);
  const rows = new data.constructor(data.length);
  for (let y = 0; y < h; y++) rows.set(data.subarray((h - 1 - y) * w * c, (h - y) * w * c), y * w * c);
  tex.image.data = rows;
  return [finish(tex), 'EXRLoader'];
}

/**
 * Loads a bake directory (served over HTTP or from a file URL): its bake.json, its GLSL ES source and its
 * textures (KTX2 where the bake lists them, else EXR). KTX2 files are read by `ktx2Loader` when one is given
 * (three's KTX2Loader after `detectSupport(renderer)`, as an engine loads its other KTX2 assets), else parsed
 * here with the ktx-parse copy three ships. `sources` says which reader read each texture.
 * @param {string} url - the directory's URL
 * @param {{ktx2Loader?: import('three/addons/loaders/KTX2Loader.js').KTX2Loader}} [options]
 * @returns {Promise<{url: string, document: object, glsl: string, textures: Object<string, DataTexture>, sources: Object<string, string>, lookups: number}>}
 */
export async function loadBake(url, { ktx2Loader } = {}) {
  const base = url.endsWith('/') ? url : `${url}/`;
  const doc = await fetchOk(joinUrl(base, 'bake.json'), 'json');
  if (doc.format !== FORMAT) throw new Error(`homofac: ${base}bake.json is not a homofac bake`);
  if (!doc.shaders || doc.shaders.glsl_es !== SHADER_FILE) throw new Error(`homofac: ${base}bake.json names no ${SHADER_FILE}`);
  if (!Array.isArray(doc.textures) || !doc.textures.every((t) => TEXTURE_NAME.test(t.name) && TEXTURE_FILE.test(t.file)
      && (t.ktx2 === undefined || TEXTURE_FILE.test(t.ktx2)))) {
    throw new Error(`homofac: ${base}bake.json: texture names and files must be P<k>, E<d>, W<t> (.exr, .ktx2)`);
  }
  const glsl = await fetchOk(joinUrl(base, SHADER_FILE), 'text');
  const entries = await Promise.all(doc.textures.map(async (t) => [`hf_${t.name}`, await loadTexture(base, t, ktx2Loader)]));
  return { url: base, document: doc, glsl, textures: Object.fromEntries(entries.map(([k, [tex]]) => [k, tex])),
    sources: Object.fromEntries(entries.map(([k, [, source]]) => [k, source])), lookups: doc.lookups };
}

// Added after three's lights_fragment_end: the bake's integrals at the shading normal and the view, in world
// space (three's normal and view vectors are in view space: the transpose of viewMatrix takes them back).
const IBL_CHUNK = /* glsl */`
#include <lights_fragment_end>
{
	vec3 hfN = normalize( ( vec4( geometryNormal, 0.0 ) * viewMatrix ).xyz );
	vec3 hfV = normalize( ( vec4( geometryViewDir, 0.0 ) * viewMatrix ).xyz );
	vec3 hfId, hfIA, hfIB;
	homofac_ibl_terms( hfN, hfV, material.roughness, hfId, hfIA, hfIB );
	vec3 hfF0 = mix( vec3( 0.04 ), material.diffuseColor, material.metalness );
	reflectedLight.indirectDiffuse += 0.96 * material.diffuseContribution * hfId * homofacIntensity;
	reflectedLight.indirectSpecular += ( hfF0 * hfIA + hfIB ) * homofacIntensity;
}
`;

/**
 * Makes `material` (MeshStandardMaterial or MeshPhysicalMaterial) take its image-based lighting from `bake`
 * instead of an environment map: patches it in place through onBeforeCompile and returns it.
 * @param {import('three').MeshStandardMaterial} material
 * @param {Awaited<ReturnType<typeof loadBake>>} bake
 * @param {{intensity?: number}} [options] - a factor on the bake's radiance (three's envMapIntensity)
 */
export function applyBake(material, bake, { intensity = 1 } = {}) {
  if (!material || !material.isMeshStandardMaterial) {
    throw new Error('homofac: applyBake takes a MeshStandardMaterial or MeshPhysicalMaterial');
  }
  material.envMap = null; // the bake replaces PMREM; scene.environment is ignored for this material
  material.userData.homofac = { intensity: { value: intensity } };
  material.onBeforeCompile = (shader) => {
    for (const [name, texture] of Object.entries(bake.textures)) shader.uniforms[name] = { value: texture };
    shader.uniforms.homofacIntensity = material.userData.homofac.intensity;
    shader.fragmentShader = shader.fragmentShader
      .replace('void main() {', `#define HOMOFAC_Y_UP\n${bake.glsl}\nuniform float homofacIntensity;\nvoid main() {`)
      .replace('#include <lights_fragment_end>', IBL_CHUNK);
  };
  material.customProgramCacheKey = () => `homofac:${bake.url}`;
  material.needsUpdate = true;
  return material;
}

/**
 * A lat-long environment in homofac's convention (row 0 up, +z up, as EXRLoader or HDRLoader return it) as the
 * equirect three.js samples in its y-up world, so that PMREM sees the environment the bake was made from:
 * three's direction (x, y, z) reads homofac's (x, -z, y). Permutes the texture's columns in place.
 * @param {import('three').DataTexture} texture
 */
export function toThreeEquirect(texture) {
  const { width: w, height: h, data } = texture.image;
  const c = data.length / (w * h);
  const out = new data.constructor(data.length);
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      const src = ((y * w + ((((w >> 1) - 1 - x) % w) + w) % w) * c);
      out.set(data.subarray(src, src + c), (y * w + x) * c);
    }
  }
  texture.image.data = out;
  texture.mapping = EquirectangularReflectionMapping;
  texture.needsUpdate = true;
  return texture;
}
