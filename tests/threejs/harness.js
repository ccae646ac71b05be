// window.hfTest: set up a scene (asset + equirect environment), then read passes back as base64 float32.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { KTX2Loader } from 'three/addons/loaders/KTX2Loader.js';
import { loadBake, applyBake } from '/js/homofac-three.js';

const state = {};

function b64(buf) {
  const bytes = new Uint8Array(buf.buffer, buf.byteOffset, buf.byteLength);
  let s = '';
  for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
  return btoa(s);
}

async function fetchFloat(url) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${url}: ${r.status}`);
  return new Float32Array(await r.arrayBuffer());
}

// The G-buffer passes: the same material, its output replaced by one of its shading inputs.
const PASSES = {
  normal: 'vec4( normalize( ( vec4( geometryNormal, 0.0 ) * viewMatrix ).xyz ), material.metalness )',
  view: 'vec4( normalize( ( vec4( geometryViewDir, 0.0 ) * viewMatrix ).xyz ), material.roughness )',
  base: 'vec4( material.diffuseColor, 1.0 )',
};

function passMaterial(material, expr) {
  const m = material.clone();
  m.envMap = null;
  m.onBeforeCompile = (shader) => {
    shader.fragmentShader = shader.fragmentShader.replace(
      '#include <dithering_fragment>', `#include <dithering_fragment>\n\tgl_FragColor = ${expr};`);
  };
  m.customProgramCacheKey = () => expr;
  return m;
}

function readTarget(target) {
  const { width, height } = target;
  const out = new Float32Array(width * height * 4);
  state.renderer.readRenderTargetPixels(target, 0, 0, width, height, out);
  return out;
}

window.hfTest = {
  ready: false, error: null,

  // opts: {asset, env: url of float32 RGBA equirect data (row 0 = bottom), envWidth, envHeight, size,
  //        cameraPosition: [x, y, z]}
  async setup(opts) {
    const size = opts.size;
    const canvas = document.createElement('canvas');
    canvas.width = canvas.height = size;
    document.body.appendChild(canvas);
    const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
    renderer.setPixelRatio(1);
    renderer.setSize(size, size, false);
    renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
    renderer.toneMapping = THREE.NoToneMapping;
    const data = await fetchFloat(opts.env);
    const env = new THREE.DataTexture(data, opts.envWidth, opts.envHeight, THREE.RGBAFormat, THREE.FloatType);
    env.mapping = THREE.EquirectangularReflectionMapping;
    env.colorSpace = THREE.LinearSRGBColorSpace;
    env.magFilter = THREE.LinearFilter;
    env.minFilter = THREE.LinearFilter;
    env.needsUpdate = true;
    const pmrem = new THREE.PMREMGenerator(renderer);
    const envRT = pmrem.fromEquirectangular(env);
    const gltf = await new GLTFLoader().loadAsync(opts.asset);
    const scene = new THREE.Scene();
    scene.add(gltf.scene);
    const meshes = [];
    gltf.scene.traverse((o) => { if (o.isMesh) meshes.push(o); });
    const camera = new THREE.PerspectiveCamera(opts.fov || 30, 1, 0.1, 100);
    camera.position.fromArray(opts.cameraPosition);
    camera.lookAt(0, 0, 0);
    const target = new THREE.WebGLRenderTarget(size, size, { type: THREE.FloatType, format: THREE.RGBAFormat,
      minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter, depthBuffer: true });
    Object.assign(state, { renderer, scene, camera, meshes, target, envTexture: envRT.texture, envRT, size,
      originals: meshes.map((m) => m.material) });
    return true;
  },

  // Renders with each mesh's material replaced by make(original) into the float target; base64 float32 RGBA.
  _render(make) {
    const { renderer, scene, camera, meshes, target, originals } = state;
    meshes.forEach((m, i) => { m.material = make(originals[i]); });
    renderer.setRenderTarget(target);
    renderer.setClearColor(0x000000, 0);
    renderer.clear();
    renderer.render(scene, camera);
    renderer.setRenderTarget(null);
    return b64(readTarget(target));
  },

  // What three's PMREM holds on the GPU: its cube render target (6 faces, RGBA half floats, every prefiltered mip
  // level it allocates) and the 16 x 16 RG half-float DFG table; [face size, mip levels, bytes].
  pmremInfo() {
    const { envRT } = state;
    const levels = envRT.texture.mipmaps.length ? envRT.texture.mipmaps : [{ width: envRT.width, height: envRT.height }];
    const cube = 6 * 8 * levels.reduce((sum, l) => sum + l.width * l.height, 0);
    return [envRT.width, levels.length, cube + 16 * 16 * 4];
  },

  gbuffer(name) { return this._render((m) => passMaterial(m, PASSES[name])); },

  // The material with three's own image-based lighting (PMREM of the environment), times `exposure`.
  _pmrem(exposure) {
    return (m) => { const c = m.clone(); c.envMap = state.envTexture; c.envMapIntensity = exposure; return c; };
  },

  // The material with homofac's drop-in (js/homofac-three.js) reading the bake loaded by loadBake.
  _homofac(exposure) { return (m) => applyBake(m.clone(), state.bake, { intensity: exposure }); },

  // The bake's KTX2 files go through three's KTX2Loader, as an engine reads them; [lookups, reader per texture].
  async loadBake(url) {
    state.bake = await loadBake(url, { ktx2Loader: new KTX2Loader().detectSupport(state.renderer) });
    return [state.bake.lookups, state.bake.sources];
  },

  // The drop-in on each material made a MeshPhysicalMaterial (its standard properties; clearcoat, sheen and
  // transmission 0): the physical material's base layer.
  _physical(exposure) {
    return (m) => {
      const p = new THREE.MeshPhysicalMaterial();
      THREE.MeshStandardMaterial.prototype.copy.call(p, m);
      p.defines = { STANDARD: '', PHYSICAL: '' };
      return applyBake(p, state.bake, { intensity: exposure });
    };
  },

  // Float radiance (base64 float32 RGBA) of 'pmrem', 'homofac' or 'physical'.
  radiance(kind) {
    return this._render(kind === 'pmrem' ? this._pmrem(1) : kind === 'physical' ? this._physical(1) : this._homofac(1));
  },

  // The 8-bit canvas (linear output, no tone mapping) of 'pmrem' or 'homofac' at `exposure`: base64 RGBA bytes.
  canvas(kind, exposure) {
    const { renderer, scene, camera, meshes, originals, size } = state;
    const make = kind === 'pmrem' ? this._pmrem(exposure) : this._homofac(exposure);
    meshes.forEach((m, i) => { m.material = make(originals[i]); });
    renderer.setRenderTarget(null);
    renderer.setClearColor(0x000000, 1);
    renderer.clear();
    renderer.render(scene, camera);
    const gl = renderer.getContext();
    const out = new Uint8Array(size * size * 4);
    gl.readPixels(0, 0, size, size, gl.RGBA, gl.UNSIGNED_BYTE, out);
    return b64(out);
  },
};
window.hfTest.ready = true;
