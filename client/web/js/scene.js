// three.js rendering of a ProgressiveLevels: one BufferGeometry over a prefix of its
// full-size buffers, grown and shrunk with setDrawRange; only the changed prefix is
// re-uploaded.
//
// Positions stay grid integers; the mesh's transform maps them to the model's units
// (origin + q * step), centred on the grid box. Flat shading takes normals from screen
// derivatives, so no normal buffer has to follow the level. A mesh with appearance
// (levels.wedges) is drawn from its render vertices, one per (vertex, wedge) pair
// (wedges.js), with its UVs and texture, vertex colours and, when it has them, its
// normals (smooth shading).

import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { FullScreenQuad } from "three/addons/postprocessing/Pass.js";

const BACKGROUND_MIN_MS = 100; // background redraws at most this often
// A frame slower than this is taken as bound by drawing, whose time grows with the faces;
// a faster one as bound by the display's refresh, whose jitter says nothing of them.
const DRAW_BOUND_MS = 50;
// What a face adds to a software GL's frame until two frames have measured it
// (SwiftShader at 1200 x 800 on two cores: 0.8-1.3 s for 871k faces).
const SOFTWARE_FACE_MS = 1e-3;
// A software GL's frame expected to take longer than this is drawn off screen
// (drawOffScreen): drawn to the canvas, the page would freeze for its whole time.
const OFFSCREEN_MS = 200;
// The GL renderers that draw on the CPU, as WEBGL_debug_renderer_info names them.
const SOFTWARE_RENDERER = /SwiftShader|llvmpipe|softpipe|software/i;
// The GL buffers cover this many times the rows (and faces) the level has when they are
// made, and are made again, larger, when the level outgrows them: three.js uploads a
// buffer whole when it makes it, and the full mesh's (16 MB for 435k vertices) held
// up the base mesh's first frame by some 50 ms on a two-core machine.
const BUFFER_GROWTH = 4;
const BUFFER_MIN_ROWS = 4096;
// How often a frame drawn off screen is asked whether the GL has finished it.
const FENCE_POLL_MS = 4;
// A GL that draws on the CPU pays for every sample: SwiftShader drew dragon's full mesh
// at 1200 x 800 in 620 ms with 4 samples and 190 ms with one. Its canvas and frames have
// one; a view at rest this long is drawn once more with POLISH_SAMPLES (polish).
const POLISH_AFTER_MS = 500;
const POLISH_SAMPLES = 4;

/** The rows of the drawn buffers that the level uses: its vertices, or with wedges its
 * render vertices. */
const levelRows = (levels) => levels.wedges?.render.count ?? levels.level;

export class MeshScene {
  /** Throws when the browser has no WebGL. */
  constructor(canvas) {
    this.canvas = canvas;
    this.softwareGL = drawsOnTheCpu();
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: !this.softwareGL });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0x1d2026);
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.01, 100);
    this.scene.add(this.camera);
    this.scene.add(new THREE.HemisphereLight(0xdde6ff, 0x40382e, 1.2));
    const key = new THREE.DirectionalLight(0xffffff, 2.2);
    key.position.set(1, 1.5, 2); // follows the camera, so the side in view is lit
    this.camera.add(key);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.addEventListener("change", () => {
      this.polishNext = false; // a polish would hold the view's next move back
      this.requestRender();
    });
    this.mesh = null;
    this.levels = null;
    this.dirty = false;
    this.pending = false;
    this.lastRender = -Infinity;
    this.timer = null; // a background redraw waiting its turn
    this.frameMs = 0; // how long the last frame took to draw
    this.frameFaces = 0; // and how many faces it drew
    this.faceMs = 0; // what a face added to a frame's time, from the last two frames
    this.onRendered = null; // (levels, level, polished) => void, after each frame shown
    this.drawing = false; // a frame drawn off screen that the GL has not finished
    this.waiting = false; // a frame asked for while one was drawing: it comes after
    this.targets = new Map(); // where such frames are drawn, by samples (offscreenTarget)
    this.copy = null; // and the quad that copies them to the canvas once finished
    this.offscreenMs = OFFSCREEN_MS; // tests set 0 to draw every frame off screen
    this.framesOffScreen = 0; // the mesh's frames drawn by drawOffScreen, for tests and benchmarks
    this.polishTimer = null; // a software GL's view at rest: polished (schedulePolish)
    this.polishNext = false; // the next frame is that polish
    this.framesPolished = 0; // for tests and benchmarks
    this.warmedFor = null; // the mesh whose frames off screen warmOffScreen prepared
    new ResizeObserver(() => this.resize()).observe(canvas);
    this.resize();
  }

  resize() {
    const { clientWidth: width, clientHeight: height } = this.canvas;
    if (!width || !height) return;
    this.renderer.setSize(width, height, false);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
    this.requestRender();
  }

  /** Show `levels` (a ProgressiveLevels), framed by its grid box. */
  show(levels) {
    this.clear();
    this.levels = levels;
    const geometry = new THREE.BufferGeometry();
    this.bindBuffers(geometry, levels);
    const names = levels.wedges?.grid.names ?? [];
    const textured = names.includes("uv") && levels.texture;
    const several = names.includes("material") && levels.materials;
    const material = new THREE.MeshStandardMaterial({
      // White under a texture or vertex colours, which the colour would tint.
      color: textured || several || names.includes("color") ? 0xffffff : 0xc9cdd6,
      roughness: 0.65,
      metalness: 0.0,
      flatShading: !names.includes("normal"),
      vertexColors: names.includes("color"),
      // Its side is set at each frame, before it is drawn (cullBackFaces).
    });
    const mesh = new THREE.Mesh(geometry, material);
    mesh.frustumCulled = false; // the bounding sphere would have to follow the level
    const { origin, step, bits } = levels.grid;
    const top = 2 ** bits - 1;
    const size = step.map((s) => s * top);
    const radius = 0.5 * Math.hypot(...size) || 1;
    mesh.scale.set(...step);
    mesh.position.set(...origin.map((o, d) => o - (origin[d] + 0.5 * size[d])));
    this.scene.add(mesh);
    this.mesh = mesh;
    this.textureShown = false;
    this.framesOffScreen = this.framesPolished = 0; // they count the mesh on screen's frames
    if (textured) this.loadTexture(levels, material);
    if (several) this.loadAtlas(levels, material, names.includes("uv"));
    this.camera.near = radius / 100;
    this.camera.far = radius * 100;
    this.camera.position.set(0, 0.2 * radius, 2.6 * radius);
    this.camera.updateProjectionMatrix();
    this.controls.target.set(0, 0, 0);
    this.controls.update();
    this.changed();
  }

  /** The geometry's attributes over the levels' buffers: positions and indices, or with
   * wedges the render vertices' positions, attributes and indices, each a prefix with
   * room to grow (BUFFER_GROWTH). Called again when the level outgrows it, or when the
   * render vertices' buffers were reallocated (they grow as pairs appear). */
  bindBuffers(geometry, levels) {
    const render = levels.wedges?.render;
    const positions = render ? render.positions : levels.positions;
    const indices = render ? render.indices : levels.indices;
    const room = (need, size) => Math.min(size, Math.max(BUFFER_MIN_ROWS, BUFFER_GROWTH * need));
    this.rowRoom = room(levelRows(levels), positions.length / 3);
    this.faceRoom = room(levels.nFaces, indices.length / 3);
    const dynamic = (array, width, rows) => {
      const attribute = new THREE.BufferAttribute(array.subarray(0, width * rows), width);
      attribute.setUsage(THREE.DynamicDrawUsage);
      return attribute;
    };
    if (geometry.getIndex()) geometry.dispose(); // frees the GL buffers of the old arrays
    for (const name of Object.keys(geometry.attributes)) geometry.deleteAttribute(name);
    geometry.setAttribute("position", dynamic(positions, 3, this.rowRoom));
    for (const [name, { array, width }] of Object.entries(render?.attributes ?? {})) {
      geometry.setAttribute(name, dynamic(array, width, this.rowRoom));
    }
    geometry.setIndex(dynamic(indices, 1, 3 * this.faceRoom));
    geometry.setDrawRange(0, 3 * levels.nFaces);
    this.generation = render?.generation;
  }

  /** The base mesh's texture image (the UVs' origin is bottom-left, as three.js's with
   * its default flipY). Shown once decoded; the mesh is drawn without it meanwhile. */
  loadTexture(levels, material) {
    const url = URL.createObjectURL(new Blob([levels.texture.bytes], { type: levels.texture.type }));
    new THREE.TextureLoader().load(
      url,
      (texture) => {
        URL.revokeObjectURL(url);
        if (this.levels !== levels) return texture.dispose();
        texture.colorSpace = THREE.SRGBColorSpace;
        material.map = texture;
        material.needsUpdate = true;
        this.textureShown = true;
        this.changed();
      },
      undefined,
      () => URL.revokeObjectURL(url), // a broken image: the mesh stays untextured
    );
  }

  /** A mesh of several materials: their looks drawn side by side in one atlas (each
   * material's image, or white, tinted by its colour), and the material's shader told to
   * sample each face's tile, chosen by the render vertices' "material" value (the same
   * at a face's three corners: a material border is a seam). UVs repeat within a tile.
   * Shown once every image is decoded (a broken one leaves its tile white). */
  async loadAtlas(levels, material, withUvs) {
    const looks = levels.materials;
    const bitmaps = await Promise.all(
      looks.map((look) =>
        withUvs && look.texture
          ? createImageBitmap(new Blob([look.texture.bytes], { type: look.texture.type })).catch(() => null)
          : null,
      ),
    );
    if (this.levels !== levels) return;
    const cells = Math.ceil(Math.sqrt(looks.length));
    const largest = Math.max(1, ...bitmaps.map((b) => (b ? Math.max(b.width, b.height) : 1)));
    const limit = Math.floor(this.renderer.capabilities.maxTextureSize / cells);
    const tile = Math.min(largest, limit, 2048);
    const canvas = document.createElement("canvas");
    canvas.width = canvas.height = cells * tile;
    const context = canvas.getContext("2d");
    looks.forEach((look, k) => {
      const x = (k % cells) * tile;
      const y = Math.floor(k / cells) * tile;
      context.globalCompositeOperation = "source-over";
      context.fillStyle = "#ffffff";
      context.fillRect(x, y, tile, tile);
      if (bitmaps[k]) context.drawImage(bitmaps[k], x, y, tile, tile);
      if (look.color) {
        const [r, g, b] = look.color.map((c) => Math.round(255 * c));
        context.globalCompositeOperation = "multiply";
        context.fillStyle = `rgb(${r}, ${g}, ${b})`;
        context.fillRect(x, y, tile, tile);
      }
    });
    bitmaps.forEach((b) => b?.close());
    const texture = new THREE.CanvasTexture(canvas);
    texture.colorSpace = THREE.SRGBColorSpace;
    material.map = texture;
    material.onBeforeCompile = (shader) => {
      shader.uniforms.atlasCells = { value: cells };
      shader.vertexShader = shader.vertexShader
        .replace("void main() {", "attribute float material;\nvarying float vMaterial;\nvoid main() {")
        .replace("#include <begin_vertex>", "#include <begin_vertex>\nvMaterial = material;");
      // Without UVs a tile's centre gives its colour.
      const uv = withUvs ? "vMapUv" : "vec2(0.5)";
      shader.fragmentShader = shader.fragmentShader
        .replace("void main() {", "uniform float atlasCells;\nvarying float vMaterial;\nvoid main() {")
        .replace(
          "#include <map_fragment>",
          `float cell = floor(vMaterial + 0.5);
          vec2 corner = vec2(mod(cell, atlasCells), atlasCells - 1.0 - floor(cell / atlasCells));
          vec2 atlasUv = (corner + fract(${uv})) / atlasCells;
          // The gradients of the unwrapped UVs: no seam of blur where fract wraps.
          diffuseColor *= textureGrad(map, atlasUv, dFdx(${uv}) / atlasCells, dFdy(${uv}) / atlasCells);`,
        );
    };
    material.needsUpdate = true;
    this.textureShown = true;
    this.changed();
  }

  clear() {
    if (!this.mesh) return;
    this.scene.remove(this.mesh);
    this.mesh.geometry.dispose();
    this.mesh.material.map?.dispose();
    this.mesh.material.dispose();
    this.mesh = null;
    this.levels = null;
    this.requestRender();
  }

  /** The levels' buffers changed (new faces, another level): upload and redraw. A
   * `background` change (a stream's frame) waits so that drawing takes at most about a
   * fifth of the time: drawing a large mesh with a software GL must not take the CPU
   * that the stream itself needs. Its wait is timed again at each change, as the mesh
   * it would draw grows; a redraw that would take more than half of `endsInMs` (when
   * the stream is due to end) is not made, since it shares the CPU with the stream's
   * decoding: the stream's end draws the full mesh. */
  changed(background = false, endsInMs = Infinity) {
    this.dirty = true;
    if (!background) this.requestRender();
    else if (2 * this.frameCost() > endsInMs) this.cancelBackground();
    else if (!this.pending || this.timer) this.requestRender(this.backgroundInterval(), true);
  }

  /** What a frame of the level as it is now would take to draw: the last frame's time plus
   * what the faces added since would add. A software GL's frame grows with the faces; a
   * GPU's hardly does, unless its frames are bound by drawing. */
  frameCost() {
    const added = Math.max(0, (this.levels?.nFaces ?? 0) - this.frameFaces);
    if (this.softwareGL) return this.frameMs + added * (this.faceMs || SOFTWARE_FACE_MS);
    return this.frameMs + (this.frameMs > DRAW_BOUND_MS ? added * this.faceMs : 0);
  }

  /** Drop a background redraw still waiting its turn: a redraw of a software GL that
   * would still be drawing when the stream ends holds the full mesh's frame back by
   * its whole time (a second for dragon), and takes the CPU the stream's decoder needs. */
  cancelBackground() {
    if (!this.timer) return;
    clearTimeout(this.timer);
    this.timer = null;
    this.pending = false;
  }

  /** How long after the last frame a background redraw may come: four times what it
   * would take (frameCost). A software GL's frame of dragon took 0.15 s at 1k faces,
   * 0.4 s at 98k and 1.1 s at 871k; timed by the last frame alone, a redraw of the
   * nearly full mesh came just before the stream's end and held the full one back by a
   * second. A GPU's frame time hardly moves with the faces (a dropped frame would make
   * it seem to), and the wait does not either. */
  backgroundInterval() {
    return Math.max(BACKGROUND_MIN_MS, 4 * this.frameCost());
  }

  /** Draw at the next animation frame, at least `minIntervalMs` after the last one; a
   * frame already coming is kept, unless `retime` (a background redraw's wait). */
  requestRender(minIntervalMs = 0, retime = false) {
    const wait = this.lastRender + minIntervalMs - performance.now();
    if (this.pending && !retime && !(this.timer && wait <= 0)) return;
    clearTimeout(this.timer); // a waiting background redraw is overtaken by this one
    this.timer = null;
    this.pending = true;
    const draw = () => requestAnimationFrame(() => this.render());
    if (wait > 0) this.timer = setTimeout(() => ((this.timer = null), draw()), wait);
    else draw();
  }

  render() {
    if (this.drawing) {
      // The last frame is still being drawn: this one follows it (finishDrawing), rather
      // than queue behind it.
      this.waiting = true;
      return;
    }
    this.pending = false;
    this.lastRender = performance.now();
    const levels = this.levels;
    const polish = this.polishNext && !this.dirty; // the view as it was: nothing new came
    this.polishNext = false;
    if (this.mesh && this.dirty) {
      const geometry = this.mesh.geometry;
      const render = levels.wedges?.render;
      const rows = levelRows(levels);
      const outgrown = rows > this.rowRoom || levels.nFaces > this.faceRoom;
      if (outgrown || (render && render.generation !== this.generation)) this.bindBuffers(geometry, levels);
      // Rows past the level are never drawn: upload the prefix only. Split records
      // touch scattered rows below it, so the whole prefix goes.
      for (const attribute of Object.values(geometry.attributes)) {
        attribute.clearUpdateRanges();
        attribute.addUpdateRange(0, attribute.itemSize * rows);
        attribute.needsUpdate = true;
      }
      const index = geometry.getIndex();
      index.clearUpdateRanges();
      index.addUpdateRange(0, 3 * levels.nFaces);
      index.needsUpdate = true;
      geometry.setDrawRange(0, 3 * levels.nFaces);
      this.dirty = false;
    }
    if (this.mesh) this.cullBackFaces(levels.closedAt(levels.level));
    const started = this.lastRender;
    const faces = levels?.nFaces ?? 0;
    const level = levels?.level; // the levels may move on while the frame is drawn
    const mesh = this.mesh; // and another mesh may be shown by then
    // The frame counts as shown at the next animation frame after it reaches the canvas
    // (as a page timing a static file's first frame counts it); its cost is the time
    // from here to then.
    const shown = () =>
      requestAnimationFrame(() => {
        if (polish) {
          // Its samples' time says nothing of the next frame's.
          if (mesh === this.mesh) this.framesPolished++;
        } else {
          const ms = performance.now() - started;
          if (this.frameFaces > 0 && faces > 1.1 * this.frameFaces) {
            this.faceMs = Math.max(0, (ms - this.frameMs) / (faces - this.frameFaces));
          }
          this.frameMs = ms;
          this.frameFaces = faces;
          if (this.softwareGL) this.schedulePolish();
        }
        // A background redraw waiting was timed before this frame's time was known.
        if (this.timer) this.requestRender(this.backgroundInterval(), true);
        if (this.warmedFor !== this.mesh) setTimeout(() => this.warmOffScreen()); // after its commit
        if (levels) this.onRendered?.(levels, level, polish);
      });
    if (polish) this.drawOffScreen(shown, POLISH_SAMPLES);
    else if (this.softwareGL && this.frameCost() > this.offscreenMs) this.drawOffScreen(shown, 0);
    else {
      this.renderer.render(this.scene, this.camera);
      shown();
    }
  }

  /** Draw only the faces turned to the camera while the level is a closed surface
   * turned outwards (ProgressiveLevels.closedAt): from outside it the picture is the
   * same, and its back faces cost a software GL about a fifth of its frame (dragon's
   * full mesh: 186 ms drawn from both sides, 145 ms culled). A level with a border, or
   * one turned inside out, is drawn from both sides, so that what is seen through a
   * hole is its inside, and an inside-out mesh shows its near side. The side is part
   * of the material's program: a level that opens a closed mesh (rare: a mesh is
   * closed at every level or at none, but for pair contractions) draws with another
   * one. Dragon's full detail came 12 % sooner (docs/performance.md). */
  cullBackFaces(closed) {
    const side = closed ? THREE.FrontSide : THREE.DoubleSide;
    const material = this.mesh.material;
    if (material.side === side) return;
    material.side = side;
    material.needsUpdate = true;
  }

  /** Whether the mesh is drawn with its back faces culled (null: no mesh). */
  get backFacesCulled() {
    return this.mesh ? this.mesh.material.side === THREE.FrontSide : null;
  }

  /** Draw the frame into a render target and copy it to the canvas once the GL has
   * finished it, then call `shown`. A frame drawn straight to the canvas is read back
   * by the browser's compositor when it composites without a GPU (a software GL), and
   * the page's main thread waits for that: a second for dragon's full mesh, while the
   * page can take no input. Off screen the page waits only for the copy, provided no
   * draw is queued ahead of the readback (below). */
  drawOffScreen(shown, samples) {
    const renderer = this.renderer;
    const target = this.offscreenTarget(samples);
    renderer.setRenderTarget(target);
    renderer.render(this.scene, this.camera);
    renderer.setRenderTarget(null);
    const gl = renderer.getContext();
    const fence = gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0);
    gl.flush();
    this.drawing = true;
    this.framesOffScreen++;
    this.warmedFor = this.mesh;
    const poll = () => {
      if (gl.getSyncParameter(fence, gl.SYNC_STATUS) !== gl.SIGNALED) {
        setTimeout(poll, FENCE_POLL_MS);
        return;
      }
      gl.deleteSync(fence);
      if (this.targets.get(samples) !== target) return this.finishDrawing(); // resized: a new frame is due
      if (this.copy.material.map !== target.texture) {
        this.copy.material.map = target.texture;
        this.copy.material.needsUpdate = true;
      }
      this.copy.render(renderer);
      // The compositor reads the canvas back at the next frame's commit, and a draw
      // issued before that commit is queued ahead of the readback: the page would wait
      // for the whole next frame. A task posted from the next animation frame runs
      // after its commit, so the next frame's draw waits for that.
      requestAnimationFrame(() => setTimeout(() => this.finishDrawing()));
      shown();
    };
    setTimeout(poll, FENCE_POLL_MS);
  }

  /** Draw a software GL's view off screen once as soon as the mesh's first frame is shown
   * on the canvas (the same picture again): the programs of frames drawn off screen are
   * not the canvas's (three.js draws into a render target in linear colour, and the copy
   * to the canvas is a draw of its own), and the GL makes them, and the code it draws
   * them with, at their first draw. Made by a stream's full frame, the first drawn off
   * screen, that held dragon's back by about 0.1 s (every frame off screen instead: the
   * base mesh's first paint 0.12 s later). Made now, of the base mesh, it takes the core
   * that the stream's decoding leaves free. */
  warmOffScreen() {
    if (!this.softwareGL || !this.mesh || this.warmedFor === this.mesh || this.drawing) return;
    this.drawOffScreen(() => {}, 0);
  }

  /** The off-screen frame is done with: draw the frame asked for meanwhile, if any. */
  finishDrawing() {
    this.drawing = false;
    if (!this.waiting) return;
    this.waiting = false;
    requestAnimationFrame(() => this.render());
  }

  /** A render target the size of the canvas's drawing buffer with `samples` samples (0:
   * none), kept while that size holds. */
  offscreenTarget(samples) {
    const size = this.renderer.getDrawingBufferSize(new THREE.Vector2());
    let target = this.targets.get(samples);
    if (target && target.width === size.x && target.height === size.y) return target;
    target?.dispose();
    target = new THREE.WebGLRenderTarget(size.x, size.y, { samples });
    target.texture.colorSpace = THREE.SRGBColorSpace;
    this.targets.set(samples, target);
    this.copy ??= new FullScreenQuad(new THREE.MeshBasicMaterial({ depthTest: false, depthWrite: false }));
    return target;
  }

  /** Draw the view once more with POLISH_SAMPLES samples when it has rested
   * POLISH_AFTER_MS after this frame (a software GL's frames have one): unless a frame
   * is coming by then (a stream's next records, a move), which asks again. */
  schedulePolish() {
    clearTimeout(this.polishTimer);
    this.polishTimer = setTimeout(() => {
      this.polishTimer = null;
      if (this.dirty || this.pending || !this.mesh) return;
      this.polishNext = true;
      this.requestRender();
    }, POLISH_AFTER_MS);
  }
}

/** Whether the page's GL draws on the CPU (a browser without a GPU, or started without
 * one): there the compositor reads the canvas back, a frame's time grows with its faces,
 * and each sample costs. Asked of a throwaway context before the renderer's own is made,
 * since whether that one is multisampled depends on it. */
function drawsOnTheCpu() {
  const gl = document.createElement("canvas").getContext("webgl2");
  if (!gl) return false; // the renderer's own context fails and says so
  const info = gl.getExtension("WEBGL_debug_renderer_info");
  const renderer = gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER);
  gl.getExtension("WEBGL_lose_context")?.loseContext();
  return SOFTWARE_RENDERER.test(String(renderer));
}
