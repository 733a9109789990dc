// The Aquarium viewer page: draws frames of one world on a canvas. Live, frames come from the server's
// WebSocket (binary, layout in aquarium_warp/viewer/server.py); on a replay page they come from the
// trajectory embedded in the page (aquarium_warp/viewer/recording.py), and nothing is sent anywhere.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const canvas = $("world");  // Canvas 2D: everything, or with WebGL2 the overlays above the agents
  const ctx = canvas.getContext("2d");
  const glCanvas = $("world-gl");  // WebGL2 (when offered): the sea, view cones and agents
  // the MP4's palette (aquarium_warp/render.py DEFAULT_PALETTE)
  const COLOURS = {
    background: "#1d2733", sea: "#acceE7", prey: "#ff8c00", preyFin: "#e66400", preyEdge: "#8c3e00", preyEye: "#19140f",
    predator: "#5c7087", predatorFin: "#425468", predatorEdge: "#222c3a", predatorEye: "#0a0c10",
    predatorStripe: "#3e4e62", predatorMarkEdge: "#0a0c10",
    preyCone: "rgba(255,225,80,0.35)", predatorCone: "rgba(230,40,40,0.25)", preyHit: "#c81e1e",
    predatorHit: "#780a3c", velocity: "#005a1e", flow: "rgba(60,110,165,0.8)", human: "#ffe000",
    inspected: "#ffffff",
  };
  const PLOT_POINTS = 400;
  // Everything the page knows; the browser tests read it through window.aquarium.
  const state = {
    frame: null, inspected: null, framesReceived: 0, framesDrawn: 0, bytesReceived: 0, fps: 0, lastError: "", connected: false,
    overlays: { view_cones: false, hit_boxes: false, velocities: false, flow: false },
    view: null, // {x, y, scale}: the world point at the canvas's top-left, canvas pixels per world px
    plots: { captures: [], polarization: [], groups: [] }, lastStep: null,
    connections: 0, // sockets opened: more than one after a reconnect
    history: [], historyBytes: 0, scrubbing: false, // the timeline: recent live frames, oldest first
    redrawAlways: false, // draw at every animation frame, new frame or not (the benchmark's draw rate)
    renderer: "canvas2d", glName: null, // "webgl2" when the agents are drawn by WebGL2 (its GPU's name)
  };
  const HISTORY_FRAMES = 1800, HISTORY_BYTES = 64 * 1024 * 1024;  // a minute at 30 fps, at most 64 MB
  window.aquarium = state;
  // Who draws the agents. ?renderer=auto (the default): WebGL2 when the browser offers it and a frame
  // holds at least GL_MIN_AGENTS agents, else Canvas 2D, which draws few agents faster where WebGL2 runs
  // on a software GPU (its fixed cost a frame); ?renderer=webgl2: WebGL2 whenever offered;
  // ?renderer=canvas2d: never.
  const GL_MIN_AGENTS = 2000;
  const asked = new URLSearchParams(location.search).get("renderer") || "auto";
  let gl = asked !== "canvas2d" && window.AquariumGL ? window.AquariumGL.create(glCanvas, COLOURS) : null;
  state.glName = gl ? gl.name : null;  // the GPU's name, when WebGL2 is offered
  let useGL = false;  // the last frame was drawn with WebGL2
  const replayData = $("replay-data");
  let socket = null;
  let dirty = false;

  function send(message) {
    if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(message));
  }

  function showError(text) {
    state.lastError = text;
    $("error").textContent = text;
  }

  // ---------------------------------------------------------------- frames
  // A frame: its header, and per agent its slot, position (uint16 quanta of the world's size), heading
  // (uint16 quanta of the circle) and velocity (float32 px/step, or null); `agents` unpacks them into
  // [x, y, heading x, heading y, velocity x, velocity y] floats per agent, for the Canvas 2D drawing.
  class Frame {
    constructor(header, slots, position, angle, velocity, flow, bytes) {
      Object.assign(this, { header, slots, position, angle, velocity, flow, bytes });
    }

    get agents() {
      const n = this.header.n, out = new Float32Array(n * 6), p = this.position, v = this.velocity;
      const sx = this.header.width / QUANTA, sy = this.header.height / QUANTA, sa = (2 * Math.PI) / QUANTA;
      for (let i = 0; i < n; i++) {
        const angle = this.angle[i] * sa;
        out[i * 6] = p[2 * i] * sx;
        out[i * 6 + 1] = p[2 * i + 1] * sy;
        out[i * 6 + 2] = Math.cos(angle);
        out[i * 6 + 3] = Math.sin(angle);
        if (v) { out[i * 6 + 4] = v[2 * i]; out[i * 6 + 5] = v[2 * i + 1]; }
      }
      return out;
    }
  }
  const QUANTA = 65536;

  function half(bits) {  // an IEEE float16 as a number
    const sign = bits & 0x8000 ? -1 : 1, exponent = (bits >> 10) & 31, mantissa = bits & 1023;
    if (exponent === 0) return sign * mantissa * 2 ** -24;
    if (exponent === 31) return mantissa ? NaN : sign * Infinity;
    return sign * (1 + mantissa / 1024) * 2 ** (exponent - 15);
  }

  // a frame of the server (layout in aquarium_warp/viewer/server.py)
  function decode(buffer) {
    const headerLength = new DataView(buffer).getUint32(0, true);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, headerLength)));
    const n = header.n;
    let offset = 4 + headerLength;
    const slots = new Uint32Array(buffer, offset, n);
    offset += 4 * n;
    const position = new Uint16Array(buffer, offset, 2 * n);
    offset += 4 * n;
    const angle = new Uint16Array(buffer, offset, n);
    offset += 2 * n + 2 * (n % 2);
    let velocity = null;
    if (header.velocities) {
      velocity = Float32Array.from(new Uint16Array(buffer, offset, 2 * n), half);
      offset += 4 * n;
    }
    const flow = header.flow_shape ? new Float32Array(buffer, offset, header.flow_shape[0] * header.flow_shape[1] * 2) : null;
    return new Frame(header, slots, position, angle, velocity, flow, buffer.byteLength);
  }

  // a frame of a replay's trajectory (aquarium_warp/viewer/recording.py), quantised as the server's
  function replayFrame(meta, f) {
    const n = f.slot.length, position = new Uint16Array(2 * n), angle = new Uint16Array(n);
    const velocity = new Float32Array(2 * n);
    const quantum = (value, size) => ((Math.round((value / size) * QUANTA) % QUANTA) + QUANTA) % QUANTA;
    for (let i = 0; i < n; i++) {
      position[2 * i] = quantum(f.x[i], meta.width);
      position[2 * i + 1] = quantum(f.y[i], meta.height);
      angle[i] = quantum(Math.atan2(f.hy[i], f.hx[i]), 2 * Math.PI);
      velocity[2 * i] = f.vx[i];
      velocity[2 * i + 1] = f.vy[i];
    }
    const header = Object.assign({}, meta, f, { n, alive_total: n, human: f.human === null ? null : { slot: f.human },
      num_worlds: 1, overlays: state.overlays, velocities: true });
    return new Frame(header, Uint32Array.from(f.slot), position, angle, velocity, null, 0);
  }

  let latest = null;  // the header of the newest frame received
  // a new frame of the run: plotted, kept in the timeline and shown unless the timeline is scrubbed
  function receive(frame) {
    const h = frame.header;
    if (latest && (latest.world !== h.world || h.step < state.lastStep)) {
      for (const key in state.plots) state.plots[key] = [];  // another world or a new episode
    }
    latest = h;
    state.framesReceived += 1;
    state.bytesReceived += frame.bytes;
    if (h.step !== state.lastStep) {
      state.lastStep = h.step;
      push("captures", h.episode_captures);
      push("polarization", h.polarization);
      push("groups", h.groups);
    }
    if (!replayData) remember(frame);
    if (!state.scrubbing) show(frame);
  }

  function show(frame) {
    const h = frame.header;
    const first = state.frame === null || state.frame.header.width !== h.width || state.frame.header.height !== h.height;
    state.frame = frame;
    if (first) fit();
    updatePanel(h);
    dirty = true;
  }

  // ---------------------------------------------------------------- timeline of the live run
  let sequence = 0;
  function remember(frame) {
    state.history.push({ seq: sequence++, frame });
    state.historyBytes += frame.bytes;
    while (state.history.length > HISTORY_FRAMES || state.historyBytes > HISTORY_BYTES) {
      state.historyBytes -= state.history.shift().frame.bytes;
    }
    const slider = $("timeline");
    slider.min = state.history[0].seq;
    slider.max = sequence - 1;
    if (!state.scrubbing) slider.value = sequence - 1;
    timelineLabel();
  }

  function timelineLabel() {
    const shown = state.frame ? state.frame.header.step : "-";
    $("timeline-label").textContent = state.scrubbing ? `step ${shown} (${state.history.length} kept)` : "live";
    $("live").disabled = !state.scrubbing;
  }

  // show the kept frame `seq` (the oldest kept if it is gone); the run goes on meanwhile
  function scrubTo(seq) {
    if (!state.history.length) return;
    const first = state.history[0].seq;
    const entry = state.history[Math.min(Math.max(seq - first, 0), state.history.length - 1)];
    state.scrubbing = true;
    show(entry.frame);
    timelineLabel();
  }

  function goLive() {
    state.scrubbing = false;
    if (state.history.length) show(state.history[state.history.length - 1].frame);
    $("timeline").value = $("timeline").max;
    timelineLabel();
  }

  function push(name, value) {
    const series = state.plots[name];
    series.push(value);
    if (series.length > PLOT_POINTS) series.shift();
  }

  const fmt = (v, digits) => (v === null || v === undefined ? "-" : Number(v).toFixed(digits));

  function updatePanel(h) {
    $("step-label").textContent = `world ${h.world}, episode ${h.episode}, step ${h.step}`
      + (state.scrubbing ? " (timeline: past frame)" : "");
    $("captures").textContent = h.episode_captures;
    $("polarization").textContent = fmt(h.polarization, 3);
    $("groups").textContent = fmt(h.groups, 0);
    $("agents").textContent = `${h.n} / ${h.alive_total}`;
    if (h.specs) $("teams").textContent = `${short(h.specs.prey)} vs ${short(h.specs.predator)}`;
    if (replayData) return;
    document.body.classList.toggle("attached", !h.controls);
    showInspection(h.inspect);
    $("play").textContent = h.playing ? "Pause" : "Play";
    $("world-count").textContent = `of ${h.num_worlds}`;
    $("world-index").max = h.num_worlds - 1;
    if (document.activeElement !== $("world-index")) $("world-index").value = h.world;
    $("record").textContent = { off: "Record", preparing: "Preparing the recorder...", on: "Stop recording" }[h.recording];
    $("record").disabled = h.recording === "preparing";  // busy until the renderer is ready
    $("record").classList.toggle("on", h.recording === "on");
    for (const team of ["prey", "predator"]) {
      const select = $(`${team}-choice`);
      if (document.activeElement !== select && h.specs) select.value = h.specs[team];
    }
    if (document.activeElement !== $("human")) $("human").value = h.human ? h.human.team : "";
    $("human-stats").textContent = h.human
      ? `${h.human.team} (slot ${h.human.slot}): captures ${h.human.captures}, reward ${h.human.reward.toFixed(1)} in ${h.human.steps} steps`
      : "";
  }

  const short = (spec) => String(spec).split("/").pop();

  function showInspection(info) {
    if (!info) {
      $("inspect").textContent = state.inspected === null ? "click an agent to inspect it; drag it to move it" : "";
      return;
    }
    const fmtNumber = (v) => (v === null ? "-" : Number(v).toFixed(3));
    $("inspect").textContent = `${info.team} (slot ${info.slot})${info.alive ? "" : ", dead"}\n`
      + `action ${info.action}, reward ${fmtNumber(info.reward)}, episode return ${fmtNumber(info.episode_return)}\n`
      + `observation (${info.observation.length}): ${info.observation.map((v) => v.toFixed(2)).join(" ")}`;
  }

  // ---------------------------------------------------------------- view: zoom and pan
  function resize() {
    const ratio = window.devicePixelRatio || 1;
    canvas.width = glCanvas.width = Math.max(1, Math.round(canvas.clientWidth * ratio));
    canvas.height = glCanvas.height = Math.max(1, Math.round(canvas.clientHeight * ratio));
    dirty = true;
  }

  function fit() {
    if (!state.frame) return;
    const h = state.frame.header;
    const scale = Math.min(canvas.width / h.width, canvas.height / h.height) * 0.98;
    state.view = { scale, x: -(canvas.width / scale - h.width) / 2, y: -(canvas.height / scale - h.height) / 2 };
    viewChanged();
  }

  let rectTimer = null;
  function viewChanged() {
    dirty = true;
    if (replayData || rectTimer) return;
    rectTimer = setTimeout(() => {  // at most ten view messages a second while dragging
      rectTimer = null;
      sendView();
    }, 100);
  }

  // the part of the world shown, widened by the longest reach of a cone or body into it
  function sendView() {
    const v = state.view;
    if (!v || !state.frame) return;
    const types = Object.values(state.frame.header.types);
    const pad = Math.max(...types.map((t) => Math.max(t.view_distance, 2 * t.radius)));
    send({ type: "view", rect: [v.x - pad, v.y - pad, v.x + canvas.width / v.scale + pad, v.y + canvas.height / v.scale + pad] });
  }

  canvas.addEventListener("wheel", (event) => {
    event.preventDefault();
    const v = state.view;
    if (!v) return;
    const ratio = window.devicePixelRatio || 1;
    const px = event.offsetX * ratio, py = event.offsetY * ratio;
    const factor = Math.exp(-event.deltaY * 0.0015);
    const wx = v.x + px / v.scale, wy = v.y + py / v.scale;
    v.scale *= factor;
    v.x = wx - px / v.scale;
    v.y = wy - py / v.scale;
    viewChanged();
  }, { passive: false });
  // the world point under a mouse event, and the agent there (its slot), nearest first, torus-aware
  function worldPoint(event) {
    const ratio = window.devicePixelRatio || 1, v = state.view;
    const rect = canvas.getBoundingClientRect();
    return [v.x + (event.clientX - rect.left) * ratio / v.scale, v.y + (event.clientY - rect.top) * ratio / v.scale];
  }
  function agentAt(x, y) {
    const f = state.frame, h = f.header, a = f.agents;
    const wrap = (d, size) => d - size * Math.round(d / size);
    let best = null, bestDistance = Infinity;
    for (let i = 0; i < h.n; i++) {
      const type = f.slots[i] < h.prey_capacity ? "prey" : "predator";
      const reach = Math.max(h.types[type].radius, 6 / state.view.scale);  // small agents: six canvas pixels
      const d = Math.hypot(wrap(a[i * 6] - x, h.width), wrap(a[i * 6 + 1] - y, h.height));
      if (d <= reach && d < bestDistance) { best = f.slots[i]; bestDistance = d; }
    }
    return best;
  }
  function inspect(slot) {
    state.inspected = slot;
    send({ type: "inspect", slot });
    showInspection(null);
    dirty = true;
  }

  // drag on an agent: moves it (live); drag elsewhere: pans; a click: inspects the agent under it
  let drag = null, moveSentAt = 0;
  canvas.addEventListener("mousedown", (event) => {
    canvas.focus();
    if (!state.view || !state.frame) return;
    const [x, y] = worldPoint(event);
    const slot = replayData || state.scrubbing ? null : agentAt(x, y);
    drag = { x: event.clientX, y: event.clientY, slot, moved: false };
  });
  window.addEventListener("mouseup", (event) => {
    if (drag && !drag.moved && !replayData) {
      inspect(drag.slot);
    } else if (drag && drag.slot !== null) {
      sendMove(event, true);
    }
    drag = null;
  });
  function sendMove(event, last) {
    const now = performance.now();
    if (!last && now - moveSentAt < 50) return;  // at most twenty moves a second
    moveSentAt = now;
    const h = state.frame.header, [x, y] = worldPoint(event);
    const wrap = (c, size) => Math.min(((c % size) + size) % size, size * (1 - 1e-6));  // into [0, size)
    send({ type: "move", slot: drag.slot, x: wrap(x, h.width), y: wrap(y, h.height) });
  }
  window.addEventListener("mousemove", (event) => {
    if (!drag || !state.view) return;
    if (Math.abs(event.clientX - drag.x) + Math.abs(event.clientY - drag.y) > 3) drag.moved = true;
    if (!drag.moved) return;
    if (drag.slot !== null) { sendMove(event, false); return; }
    const ratio = window.devicePixelRatio || 1;
    state.view.x -= (event.clientX - drag.x) * ratio / state.view.scale;
    state.view.y -= (event.clientY - drag.y) * ratio / state.view.scale;
    drag.x = event.clientX;
    drag.y = event.clientY;
    viewChanged();
  });
  canvas.addEventListener("dblclick", fit);
  window.addEventListener("resize", () => { resize(); fit(); });

  // ---------------------------------------------------------------- drawing
  // Fish (prey) and sharks (predators) seen from above, nose along +u, in units of the hit-box radius:
  // the shapes of the MP4's rasteriser (kernels/render.py prey_part, predator_part).
  function ellipse(path, cu, a, b) { path.ellipse(cu, 0, a, b, 0, 0, 2 * Math.PI); }
  function mirrored(path, points) {  // a polygon and its mirror image across the u axis
    for (const sign of [1, -1]) {
      path.moveTo(points[0][0], sign * points[0][1]);
      for (const [u, v] of points.slice(1)) path.lineTo(u, sign * v);
      path.closePath();
    }
  }
  const SHAPES = { prey: {}, predator: {} };
  (function buildShapes() {
    const fish = SHAPES.prey;
    fish.fins = new Path2D();
    mirrored(fish.fins, [[-0.6, 0], [-0.95, 0.34], [-0.96, 0.14], [-0.82, 0]]);  // forked tail
    mirrored(fish.fins, [[0.18, 0.24], [-0.06, 0.27], [-0.16, 0.46]]);  // pectoral fins
    fish.body = new Path2D();
    ellipse(fish.body, 0.14, 0.56, 0.3);
    fish.stalk = new Path2D();
    mirrored(fish.stalk, [[-0.25, 0], [-0.3, 0.17], [-0.66, 0.07], [-0.66, 0]]);
    fish.stripe = null;
    fish.eyes = new Path2D();
    for (const v of [0.14, -0.14]) { fish.eyes.moveTo(0.47, v); fish.eyes.arc(0.4, v, 0.07, 0, 2 * Math.PI); }
    const shark = SHAPES.predator;
    shark.fins = new Path2D();
    mirrored(shark.fins, [[0.34, 0.15], [-0.06, 0.2], [-0.2, 0.6]]);  // pectoral fins
    mirrored(shark.fins, [[-0.6, 0.07], [-0.96, 0.28], [-0.8, 0]]);  // crescent tail
    shark.body = new Path2D();  // an ellipse narrowed ahead of u = 0.3 into a pointed snout
    const outline = [];
    for (let k = 0; k <= 48; k++) {
      const angle = Math.PI * (k / 48), u = 0.05 + 0.85 * Math.cos(angle);
      const narrow = u > 0.3 ? 1 - (0.45 * (u - 0.3)) / 0.6 : 1;
      outline.push([u, 0.23 * narrow * Math.sin(angle)]);
    }
    shark.body.moveTo(outline[0][0], 0);
    for (const [u, v] of outline) shark.body.lineTo(u, v);
    for (const [u, v] of outline.slice().reverse()) shark.body.lineTo(u, -v);
    shark.body.closePath();
    shark.stalk = null;
    shark.stripe = new Path2D();  // the dorsal fin seen from above: a dark wedge on the spine
    mirrored(shark.stripe, [[0.18, 0], [-0.12, 0.07], [-0.3, 0]]);
    shark.eyes = new Path2D();
    for (const v of [0.1, -0.1]) { shark.eyes.moveTo(0.595, v); shark.eyes.arc(0.56, v, 0.035, 0, 2 * Math.PI); }
  })();

  // one detailed agent: the canvas transform maps (u, v) to the world around (x, y); outline `edge` world px
  function drawShape(c, type, x, y, hx, hy, r, base, edge) {
    const s = SHAPES[type];
    c.setTransform(base.a * r * hx, base.a * r * hy, -base.a * r * hy, base.a * r * hx,
      base.e + base.a * x, base.f + base.a * y);
    c.fillStyle = COLOURS[type + "Fin"];
    c.fill(s.fins);
    c.fillStyle = COLOURS[type];
    if (s.stalk) c.fill(s.stalk);
    c.fill(s.body);
    c.lineWidth = edge / r;
    c.strokeStyle = COLOURS[type + "Edge"];
    c.stroke(s.body);
    if (s.stripe) { c.fillStyle = COLOURS[type + "Stripe"]; c.fill(s.stripe); }
    c.fillStyle = COLOURS[type + "Eye"];
    c.fill(s.eyes);
  }

  // Zoomed out, shapes turn into marks that stay distinct: a plain oval along the heading below
  // DETAIL_PX canvas pixels of radius (as the MP4 does below 3 image pixels), and below DOT_PX a square
  // dot for a prey and a larger outlined diamond for a predator.
  const DETAIL_PX = 3, DOT_PX = 1.5;
  function markOf(type, r, px) {
    if (r / px >= DETAIL_PX) return "shape";
    return r / px >= DOT_PX ? "oval" : type === "prey" ? "dot" : "diamond";
  }
  function traceMark(c, mark, x, y, hx, hy, r, px) {
    if (mark === "oval") {
      c.moveTo(x + hx * 0.8 * r, y + hy * 0.8 * r);
      c.ellipse(x - 0.1 * r * hx, y - 0.1 * r * hy, 0.9 * r, 0.4 * r, Math.atan2(hy, hx), 0, 2 * Math.PI);
    } else if (mark === "dot") {
      c.rect(x - 1.5 * px, y - 1.5 * px, 3 * px, 3 * px);
    } else {
      const d = 4 * px;
      c.moveTo(x, y - d); c.lineTo(x + d, y); c.lineTo(x, y + d); c.lineTo(x - d, y); c.closePath();
    }
  }

  // The world is a torus: `fn(x', y')` for each copy of the point (x, y) shifted by whole world sizes
  // whose disc of radius `reach` touches the world's rectangle (one copy, more near an edge).
  function copies(x, y, reach, w, h, fn) {
    for (let ox = -w; ox <= w; ox += w) {
      const cx = x + ox;
      if (cx + reach < 0 || cx - reach > w) continue;
      for (let oy = -h; oy <= h; oy += h) {
        const cy = y + oy;
        if (cy + reach < 0 || cy - reach > h) continue;
        fn(cx, cy);
      }
    }
  }

  // Canvas 2D: the view cones and the bodies (`a`: frame.agents)
  function drawAgents(frame, a, px, base, world) {
    const h = frame.header, slots = frame.slots, n = h.n, W = h.width, H = h.height;
    const typeOf = (i) => (slots[i] < h.prey_capacity ? "prey" : "predator");
    const halfDiagonal = 0.5 * Math.hypot(W, H);
    if (state.overlays.view_cones) {
      for (const type of ["prey", "predator"]) {
        const t = h.types[type], half = (t.fov / 2) * Math.PI / 180;
        const reach = Math.min(t.view_distance, halfDiagonal);  // beyond it the cone covers the world
        ctx.fillStyle = type === "prey" ? COLOURS.preyCone : COLOURS.predatorCone;
        ctx.beginPath();
        for (let i = 0; i < n; i++) {
          if (typeOf(i) !== type) continue;
          const angle = Math.atan2(a[i * 6 + 3], a[i * 6 + 2]);
          copies(a[i * 6], a[i * 6 + 1], reach, W, H, (x, y) => {
            if (t.fov < 360) ctx.moveTo(x, y); else ctx.moveTo(x + reach, y);
            ctx.arc(x, y, reach, angle - half, angle + half);
            ctx.closePath();
          });
        }
        ctx.fill();
      }
    }
    // bodies: batched paths of marks when small (large swarms stay fast), the full shapes when large
    for (const type of ["prey", "predator"]) {
      const r = h.types[type].radius, mark = markOf(type, r, px);
      const reach = Math.max(r, 4 * px);
      if (mark === "shape") {
        for (let i = 0; i < n; i++) {
          if (typeOf(i) !== type) continue;
          let hx = a[i * 6 + 2], hy = a[i * 6 + 3];
          if (hx * hx + hy * hy < 1e-12) { hx = 0; hy = -1; }  // no heading recorded: point up
          copies(a[i * 6], a[i * 6 + 1], reach, W, H, (x, y) => drawShape(ctx, type, x, y, hx, hy, r, base, px));
        }
        world();
        continue;
      }
      ctx.beginPath();
      for (let i = 0; i < n; i++) {
        if (typeOf(i) !== type) continue;
        const hx = a[i * 6 + 2], hy = a[i * 6 + 3];
        copies(a[i * 6], a[i * 6 + 1], reach, W, H, (x, y) => traceMark(ctx, mark, x, y, hx, hy, r, px));
      }
      ctx.fillStyle = COLOURS[type];
      ctx.fill();
      if (mark === "diamond") {
        ctx.lineWidth = px;
        ctx.strokeStyle = COLOURS.predatorMarkEdge;
        ctx.stroke();
      }
    }
  }

  // With WebGL2 the GL canvas draws the sea, the view cones and the agents, and the Canvas 2D one above
  // it the other overlays; without, Canvas 2D draws everything.
  function draw() {
    const frame = state.frame;
    const v = state.view;
    const ov = state.overlays;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    useGL = gl !== null && frame !== null && (asked === "webgl2" || frame.header.n >= GL_MIN_AGENTS);
    state.renderer = useGL ? "webgl2" : "canvas2d";
    glCanvas.hidden = !useGL;
    if (useGL) {
      gl.draw(frame, v, ov.view_cones, markOf);
      ctx.clearRect(0, 0, canvas.width, canvas.height);
    } else {
      ctx.fillStyle = COLOURS.background;
      ctx.fillRect(0, 0, canvas.width, canvas.height);
    }
    if (!frame || !v) return;
    const h = frame.header, slots = frame.slots, n = h.n;
    const a = !useGL || ov.hit_boxes || (ov.velocities && frame.velocity) ? frame.agents : null;
    const W = h.width, H = h.height;
    const base = { a: v.scale, e: -v.x * v.scale, f: -v.y * v.scale };
    const world = () => ctx.setTransform(base.a, 0, 0, base.a, base.e, base.f);
    world();
    if (!useGL) {
      ctx.fillStyle = COLOURS.sea;
      ctx.fillRect(0, 0, W, H);
    }
    ctx.save();
    ctx.beginPath();
    ctx.rect(0, 0, W, H);
    ctx.clip();  // the world's rectangle; what reaches past an edge is drawn again across the seam
    const px = 1 / v.scale;  // one canvas pixel in world px
    if (ov.flow && frame.flow) drawFlow(frame, px);
    const typeOf = (i) => (slots[i] < h.prey_capacity ? "prey" : "predator");
    if (!useGL) drawAgents(frame, a, px, base, world);
    ctx.lineWidth = px;
    if (ov.hit_boxes) {
      for (const type of ["prey", "predator"]) {
        const r = h.types[type].radius;
        ctx.strokeStyle = COLOURS[type + "Hit"];
        ctx.beginPath();
        for (let i = 0; i < n; i++) {
          if (typeOf(i) !== type) continue;
          copies(a[i * 6], a[i * 6 + 1], r, W, H, (x, y) => { ctx.moveTo(x + r, y); ctx.arc(x, y, r, 0, 2 * Math.PI); });
        }
        ctx.stroke();
      }
    }
    if (ov.velocities && frame.velocity) {  // the move of ten steps, as the rasteriser draws it
      ctx.strokeStyle = COLOURS.velocity;
      ctx.beginPath();
      for (let i = 0; i < n; i++) {
        const dx = 10 * a[i * 6 + 4], dy = 10 * a[i * 6 + 5];
        copies(a[i * 6], a[i * 6 + 1], Math.hypot(dx, dy), W, H, (x, y) => { ctx.moveTo(x, y); ctx.lineTo(x + dx, y + dy); });
      }
      ctx.stroke();
    }
    const rings = [];  // the human's agent (yellow) and the inspected one (white)
    if (h.human) rings.push([h.human.slot, COLOURS.human]);
    if (state.inspected !== null) rings.push([state.inspected, COLOURS.inspected]);
    for (const [slot, colour] of rings) {
      for (let i = 0; i < n; i++) {
        if (slots[i] !== slot) continue;
        const r = h.types[typeOf(i)].radius * 1.6 + 4 * px;
        ctx.strokeStyle = colour;
        ctx.lineWidth = 3 * px;
        ctx.beginPath();
        const x = (frame.position[2 * i] * W) / QUANTA, y = (frame.position[2 * i + 1] * H) / QUANTA;
        copies(x, y, r + 3 * px, W, H, (cx, cy) => { ctx.moveTo(cx + r, cy); ctx.arc(cx, cy, r, 0, 2 * Math.PI); });
        ctx.stroke();
      }
    }
    ctx.restore();
  }

  // the legend's icons, drawn with the world's own marks and colours
  function drawLegend() {
    const ratio = window.devicePixelRatio || 1;
    document.querySelectorAll("canvas.icon").forEach((icon) => {
      icon.width = icon.clientWidth * ratio;
      icon.height = icon.clientHeight * ratio;
      const c = icon.getContext("2d"), w = icon.width, h = icon.height, r = 0.45 * w;
      const [type, kind] = icon.dataset.icon.split("-");
      const base = { a: 1, e: 0, f: 0 };
      if (type === "human" || type === "inspected") {
        c.strokeStyle = COLOURS[type];
        c.lineWidth = 2 * ratio;
        c.beginPath();
        c.arc(w / 2, h / 2, 0.4 * h, 0, 2 * Math.PI);
        c.stroke();
      } else if (kind === "cone") {
        c.fillStyle = COLOURS[type + "Cone"];
        c.beginPath();
        c.moveTo(0.1 * w, h / 2);
        c.arc(0.1 * w, h / 2, 0.85 * w, -0.5, 0.5);
        c.closePath();
        c.fill();
      } else if (kind) {
        c.beginPath();
        traceMark(c, kind, w / 2, h / 2, 1, 0, r, ratio);
        c.fillStyle = COLOURS[type];
        c.fill();
        if (kind === "diamond") { c.lineWidth = ratio; c.strokeStyle = COLOURS.predatorMarkEdge; c.stroke(); }
      } else {
        drawShape(c, type, w / 2, h / 2, 1, 0, r, base, ratio);
      }
    });
  }

  function drawFlow(frame, px) {
    const [rows, cols] = frame.header.flow_shape;
    const cw = frame.header.width / cols, ch = frame.header.height / rows, f = frame.flow;
    const longest = 0.9 * Math.min(cw, ch);
    ctx.strokeStyle = COLOURS.flow;
    ctx.lineWidth = 1.5 * px;
    ctx.beginPath();
    for (let i = 0; i < rows; i++) {
      for (let j = 0; j < cols; j++) {
        let dx = f[(i * cols + j) * 2] * 10, dy = f[(i * cols + j) * 2 + 1] * 10;
        const length = Math.hypot(dx, dy);
        if (length < px) continue;
        if (length > longest) { dx *= longest / length; dy *= longest / length; }
        const x = (j + 0.5) * cw, y = (i + 0.5) * ch;
        ctx.moveTo(x, y);
        ctx.lineTo(x + dx, y + dy);
        const back = Math.atan2(dy, dx) + Math.PI, head = Math.min(0.35 * Math.hypot(dx, dy), 8 * px);
        ctx.lineTo(x + dx + head * Math.cos(back - 0.4), y + dy + head * Math.sin(back - 0.4));
        ctx.moveTo(x + dx, y + dy);
        ctx.lineTo(x + dx + head * Math.cos(back + 0.4), y + dy + head * Math.sin(back + 0.4));
      }
    }
    ctx.stroke();
  }

  function drawPlot(plot) {
    const series = state.plots[plot.dataset.label].filter((v) => v !== null);
    const ratio = window.devicePixelRatio || 1;
    plot.width = plot.clientWidth * ratio;
    plot.height = plot.clientHeight * ratio;
    const c = plot.getContext("2d");
    c.fillStyle = "#9fb0c0";
    c.font = `${11 * ratio}px system-ui`;
    if (series.length === 0) { c.fillText(plot.dataset.label, 4, 12 * ratio); return; }
    let low = Math.min(...series), high = Math.max(...series);
    if (high === low) { high += 0.5; low -= 0.5; }
    c.strokeStyle = "#ffb060";
    c.lineWidth = ratio;
    c.beginPath();
    series.forEach((value, i) => {
      const x = (i / Math.max(1, PLOT_POINTS - 1)) * plot.width;
      const y = plot.height - 2 - ((value - low) / (high - low)) * (plot.height - 16 * ratio);
      if (i === 0) c.moveTo(x, y); else c.lineTo(x, y);
    });
    c.stroke();
    c.fillText(`${plot.dataset.label} ${Number(series[series.length - 1]).toFixed(plot.dataset.label === "polarization" ? 3 : 0)}`
      + `  [${Number(low).toFixed(2)}, ${Number(high).toFixed(2)}]`, 4, 12 * ratio);
  }

  // RGB of canvas pixel (column, row) as the page shows it (the tests read it): drawn now, the Canvas 2D
  // overlays over the WebGL2 canvas
  state.pixel = (column, row) => {
    draw();
    const top = ctx.getImageData(column, row, 1, 1).data;
    if (!useGL) return Array.from(top.slice(0, 3));
    const alpha = top[3] / 255;
    return gl.pixel(column, row).map((c, k) => Math.round(top[k] * alpha + c * (1 - alpha)));
  };
  state.setView = (view) => { state.view = Object.assign({}, view); viewChanged(); };

  let fpsCount = 0, fpsSince = performance.now(), plotsAt = 0;
  function animate(now) {
    if (gl && gl.lost()) {  // the GPU was taken away: Canvas 2D from now on
      gl = null;
      state.glName = null;
      dirty = true;
    }
    if (replayData) replayTick(now);
    if (dirty || state.redrawAlways) {
      dirty = false;
      draw();
      state.framesDrawn += 1;
      fpsCount += 1;
    }
    if (now - fpsSince >= 1000) {
      state.fps = (fpsCount * 1000) / (now - fpsSince);
      fpsCount = 0;
      fpsSince = now;
      $("fps-label").textContent = `${state.fps.toFixed(1)} fps (${useGL ? "WebGL2" : "Canvas 2D"})`;
    }
    if (now - plotsAt > 250) {  // plots four times a second: they need not keep up with the world
      plotsAt = now;
      document.querySelectorAll("canvas.plot").forEach(drawPlot);
    }
    requestAnimationFrame(animate);
  }

  // ---------------------------------------------------------------- controls
  for (const name of Object.keys(state.overlays)) {
    $(`ov-${name}`).addEventListener("change", (event) => {
      state.overlays[name] = event.target.checked;
      send(Object.assign({ type: "overlays" }, state.overlays));
      dirty = true;
    });
  }

  // held keys -> a direction on the screen's axes (y down, as the world's); sent when it changes
  const KEYS = { ArrowLeft: [-1, 0], KeyA: [-1, 0], ArrowRight: [1, 0], KeyD: [1, 0], ArrowUp: [0, -1], KeyW: [0, -1],
    ArrowDown: [0, 1], KeyS: [0, 1] };
  const held = new Set();
  let sentKeys = "0,0";
  function keysChanged() {
    let dx = 0, dy = 0;
    for (const code of held) { dx += KEYS[code][0]; dy += KEYS[code][1]; }
    dx = Math.sign(dx); dy = Math.sign(dy);
    if (`${dx},${dy}` === sentKeys) return;
    sentKeys = `${dx},${dy}`;
    send({ type: "keys", dx, dy });
  }
  window.addEventListener("keydown", (event) => {
    if (!(event.code in KEYS) || event.target.tagName === "INPUT" || event.target.tagName === "SELECT") return;
    event.preventDefault();
    held.add(event.code);
    keysChanged();
  });
  window.addEventListener("keyup", (event) => {
    if (!(event.code in KEYS)) return;
    held.delete(event.code);
    keysChanged();
  });

  // The socket, opened again after it closes (a server restarted, a network blip): at 0.25 s, then
  // twice as long each time up to 4 s; the page's own settings (overlays, view, inspected agent) go again.
  let retryMs = 250;
  function connect() {
    socket = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}${location.pathname.replace(/[^/]*$/, "")}ws`);
    socket.binaryType = "arraybuffer";
    socket.onopen = () => {
      retryMs = 250;
      state.connected = true;
      state.connections += 1;
      send(Object.assign({ type: "overlays" }, state.overlays));
      if (state.inspected !== null) send({ type: "inspect", slot: state.inspected });
      sendView();
    };
    socket.onclose = () => {
      const wasConnected = state.connected;
      state.connected = false;
      $("step-label").textContent = `disconnected from the server: reconnecting in ${(retryMs / 1000).toFixed(2)} s`;
      setTimeout(connect, retryMs);
      if (!wasConnected) retryMs = Math.min(2 * retryMs, 4000);
    };
    socket.onmessage = (event) => {
      if (event.data instanceof ArrayBuffer) { receive(decode(event.data)); return; }
      const message = JSON.parse(event.data);
      if (message.type === "error") showError(message.message);
      else if (message.type === "notice") $("notice").textContent = message.message;
      else if (message.type === "hello") fillChoices(message.choices);
    };
  }

  function setupLive() {
    connect();
    $("timeline").addEventListener("input", (event) => scrubTo(Number(event.target.value)));
    $("live").addEventListener("click", goLive);
    $("play").addEventListener("click", () => {
      send({ type: state.frame && state.frame.header.playing ? "pause" : "play" });
    });
    $("step").addEventListener("click", () => send({ type: "step" }));
    $("reset").addEventListener("click", () => send({ type: "reset" }));
    $("speed").addEventListener("change", (event) => send({ type: "speed", value: Number(event.target.value) }));
    $("world-index").addEventListener("change", (event) => send({ type: "world", index: Number(event.target.value) }));
    $("human").addEventListener("change", (event) => { send({ type: "human", team: event.target.value || null }); canvas.focus(); });
    $("record").addEventListener("click", () => send({ type: "record", on: !(state.frame && state.frame.header.recording === "on") }));
    for (const team of ["prey", "predator"]) {
      $(`${team}-choice`).addEventListener("change", (event) => { showError(""); send({ type: "policy", team, spec: event.target.value }); });
      $(`${team}-apply`).addEventListener("click", () => { showError(""); send({ type: "policy", team, spec: $(`${team}-spec`).value }); });
    }
  }

  function fillChoices(choices) {
    for (const team of ["prey", "predator"]) {
      const select = $(`${team}-choice`);
      select.replaceChildren(...choices[team].map((spec) => new Option(short(spec), spec)));
      if (state.frame && state.frame.header.specs) select.value = state.frame.header.specs[team];
    }
  }

  // a replay plays its frames at 30 per second times the speed; Step and the scrubber move by hand
  let replay = null;
  function setupReplay() {
    document.body.classList.add("replay");
    const data = JSON.parse(replayData.textContent);
    replay = { meta: data.meta, frames: data.frames, index: 0, playing: true, speed: 1, last: null, credit: 0 };
    $("scrub").max = data.frames.length - 1;
    $("play").addEventListener("click", () => { replay.playing = !replay.playing; $("play").textContent = replay.playing ? "Pause" : "Play"; });
    $("step").addEventListener("click", () => { replay.playing = false; $("play").textContent = "Play"; showReplay(replay.index + 1); });
    $("speed").addEventListener("change", (event) => { replay.speed = Number(event.target.value); });
    $("scrub").addEventListener("input", (event) => showReplay(Number(event.target.value)));
    showReplay(0);
  }

  function showReplay(index) {
    replay.index = index % replay.frames.length;
    $("scrub").value = replay.index;
    receive(replayFrame(replay.meta, replay.frames[replay.index]));
  }

  function replayTick(now) {
    if (replay.last === null) replay.last = now;
    if (replay.playing) {
      replay.credit += ((now - replay.last) / 1000) * 30 * replay.speed;
      const steps = Math.floor(replay.credit);
      if (steps > 0) { replay.credit -= steps; showReplay(replay.index + steps); }
    }
    replay.last = now;
  }

  resize();
  drawLegend();
  if (replayData) setupReplay(); else setupLive();
  requestAnimationFrame(animate);
})();
