// The Aquarium viewer page: draws frames of one world on a canvas. Live, frames come from the server's
// WebSocket (binary, layout in aquarium_warp/viewer/server.py); on a replay page they come from the
// trajectory embedded in the page (aquarium_warp/viewer/recording.py), and nothing is sent anywhere.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const canvas = $("world");
  const ctx = canvas.getContext("2d");
  const COLOURS = {
    sea: "#acceE7", prey: "#ff8c00", preyEdge: "#8c3e00", predator: "#5c7087", predatorEdge: "#222c3a",
    preyCone: "rgba(255,225,80,0.30)", predatorCone: "rgba(230,40,40,0.20)", hit: "#c81e1e",
    velocity: "#005a1e", flow: "rgba(60,110,165,0.8)", human: "#ffe000",
  };
  const PLOT_POINTS = 400;
  // Everything the page knows; the browser tests read it through window.aquarium.
  const state = {
    frame: null, framesReceived: 0, framesDrawn: 0, fps: 0, lastError: "", connected: false,
    overlays: { view_cones: false, hit_boxes: false, velocities: false, flow: false },
    view: null, // {x, y, scale}: the world point at the canvas's top-left, canvas pixels per world px
    plots: { captures: [], polarization: [], groups: [] }, lastStep: null,
  };
  window.aquarium = state;
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
  function decode(buffer) {
    const headerLength = new DataView(buffer).getUint32(0, true);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, headerLength)));
    let offset = 4 + headerLength;
    const agents = new Float32Array(buffer, offset, header.n * 6);
    offset += header.n * 24;
    const slots = new Uint32Array(buffer, offset, header.n);
    offset += header.n * 4;
    const flow = header.flow_shape ? new Float32Array(buffer, offset, header.flow_shape[0] * header.flow_shape[1] * 2) : null;
    return { header, agents, slots, flow };
  }

  function replayFrame(meta, f) {
    const n = f.slot.length;
    const agents = new Float32Array(n * 6);
    for (let i = 0; i < n; i++) {
      agents.set([f.x[i], f.y[i], f.hx[i], f.hy[i], f.vx[i], f.vy[i]], i * 6);
    }
    const header = Object.assign({}, meta, f, { n, alive_total: n, human: f.human === null ? null : { slot: f.human },
      num_worlds: 1, overlays: state.overlays });
    return { header, agents, slots: Uint32Array.from(f.slot), flow: null };
  }

  function receive(frame) {
    const h = frame.header;
    const first = state.frame === null || state.frame.header.width !== h.width || state.frame.header.height !== h.height;
    if (state.frame && (state.frame.header.world !== h.world || h.step < state.lastStep)) {
      for (const key in state.plots) state.plots[key] = [];  // another world or a new episode
    }
    state.frame = frame;
    state.framesReceived += 1;
    if (h.step !== state.lastStep) {
      state.lastStep = h.step;
      push("captures", h.episode_captures);
      push("polarization", h.polarization);
      push("groups", h.groups);
    }
    if (first) fit();
    updatePanel(h);
    dirty = true;
  }

  function push(name, value) {
    const series = state.plots[name];
    series.push(value);
    if (series.length > PLOT_POINTS) series.shift();
  }

  const fmt = (v, digits) => (v === null || v === undefined ? "-" : Number(v).toFixed(digits));

  function updatePanel(h) {
    $("step-label").textContent = `world ${h.world}, episode ${h.episode}, step ${h.step}`;
    $("captures").textContent = h.episode_captures;
    $("polarization").textContent = fmt(h.polarization, 3);
    $("groups").textContent = fmt(h.groups, 0);
    $("agents").textContent = `${h.n} / ${h.alive_total}`;
    if (h.specs) $("teams").textContent = `${short(h.specs.prey)} vs ${short(h.specs.predator)}`;
    if (replayData) return;
    $("play").textContent = h.playing ? "Pause" : "Play";
    $("world-count").textContent = `of ${h.num_worlds}`;
    $("world-index").max = h.num_worlds - 1;
    if (document.activeElement !== $("world-index")) $("world-index").value = h.world;
    $("record").textContent = h.recording ? "Stop recording" : "Record";
    $("record").classList.toggle("on", !!h.recording);
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

  // ---------------------------------------------------------------- view: zoom and pan
  function resize() {
    const ratio = window.devicePixelRatio || 1;
    canvas.width = Math.max(1, Math.round(canvas.clientWidth * ratio));
    canvas.height = Math.max(1, Math.round(canvas.clientHeight * ratio));
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
      const v = state.view;
      send({ type: "view", rect: [v.x, v.y, v.x + canvas.width / v.scale, v.y + canvas.height / v.scale] });
    }, 100);
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
  let drag = null;
  canvas.addEventListener("mousedown", (event) => { drag = { x: event.clientX, y: event.clientY }; canvas.focus(); });
  window.addEventListener("mouseup", () => { drag = null; });
  window.addEventListener("mousemove", (event) => {
    if (!drag || !state.view) return;
    const ratio = window.devicePixelRatio || 1;
    state.view.x -= (event.clientX - drag.x) * ratio / state.view.scale;
    state.view.y -= (event.clientY - drag.y) * ratio / state.view.scale;
    drag = { x: event.clientX, y: event.clientY };
    viewChanged();
  });
  canvas.addEventListener("dblclick", fit);
  window.addEventListener("resize", () => { resize(); fit(); });

  // ---------------------------------------------------------------- drawing
  function draw() {
    const frame = state.frame;
    const v = state.view;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = "#1d2733";
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    if (!frame || !v) return;
    const h = frame.header, a = frame.agents, slots = frame.slots, n = h.n;
    ctx.setTransform(v.scale, 0, 0, v.scale, -v.x * v.scale, -v.y * v.scale);
    ctx.fillStyle = COLOURS.sea;
    ctx.fillRect(0, 0, h.width, h.height);
    ctx.save();
    ctx.beginPath();
    ctx.rect(0, 0, h.width, h.height);
    ctx.clip();  // cones and arrows stop at the world's edge
    const px = 1 / v.scale;  // one canvas pixel in world px
    const ov = state.overlays;
    if (ov.flow && frame.flow) drawFlow(frame, px);
    const typeOf = (i) => (slots[i] < h.prey_capacity ? "prey" : "predator");
    if (ov.view_cones) {
      for (let i = 0; i < n; i++) {
        const t = h.types[typeOf(i)], x = a[i * 6], y = a[i * 6 + 1];
        const angle = Math.atan2(a[i * 6 + 3], a[i * 6 + 2]), half = (t.fov / 2) * Math.PI / 180;
        ctx.fillStyle = typeOf(i) === "prey" ? COLOURS.preyCone : COLOURS.predatorCone;
        ctx.beginPath();
        if (t.fov < 360) ctx.moveTo(x, y);
        ctx.arc(x, y, t.view_distance, angle - half, angle + half);
        ctx.closePath();
        ctx.fill();
      }
    }
    // bodies: a path per type; below ~1.5 canvas pixels of radius a square dot (large swarms stay fast)
    for (const type of ["prey", "predator"]) {
      const r = h.types[type].radius;
      const dots = r / px < 1.5;
      ctx.beginPath();
      for (let i = 0; i < n; i++) {
        if (typeOf(i) !== type) continue;
        const x = a[i * 6], y = a[i * 6 + 1], hx = a[i * 6 + 2], hy = a[i * 6 + 3];
        if (dots) {
          ctx.rect(x - 1.5 * px, y - 1.5 * px, 3 * px, 3 * px);
        } else {  // a body pointing along the heading: nose, two flanks, tail notch
          const sx = -hy, sy = hx;
          ctx.moveTo(x + hx * r, y + hy * r);
          ctx.lineTo(x - hx * r * 0.6 + sx * r * 0.55, y - hy * r * 0.6 + sy * r * 0.55);
          ctx.lineTo(x - hx * r * 0.3, y - hy * r * 0.3);
          ctx.lineTo(x - hx * r * 0.6 - sx * r * 0.55, y - hy * r * 0.6 - sy * r * 0.55);
          ctx.closePath();
        }
      }
      ctx.fillStyle = COLOURS[type];
      ctx.fill();
      if (!dots) {
        ctx.lineWidth = px;
        ctx.strokeStyle = COLOURS[type + "Edge"];
        ctx.stroke();
      }
    }
    ctx.lineWidth = px;
    if (ov.hit_boxes) {
      ctx.strokeStyle = COLOURS.hit;
      ctx.beginPath();
      for (let i = 0; i < n; i++) {
        const r = h.types[typeOf(i)].radius;
        ctx.moveTo(a[i * 6] + r, a[i * 6 + 1]);
        ctx.arc(a[i * 6], a[i * 6 + 1], r, 0, 2 * Math.PI);
      }
      ctx.stroke();
    }
    if (ov.velocities) {  // the move of ten steps, as the rasteriser draws it
      ctx.strokeStyle = COLOURS.velocity;
      ctx.beginPath();
      for (let i = 0; i < n; i++) {
        ctx.moveTo(a[i * 6], a[i * 6 + 1]);
        ctx.lineTo(a[i * 6] + 10 * a[i * 6 + 4], a[i * 6 + 1] + 10 * a[i * 6 + 5]);
      }
      ctx.stroke();
    }
    if (h.human) {
      for (let i = 0; i < n; i++) {
        if (slots[i] !== h.human.slot) continue;
        ctx.strokeStyle = COLOURS.human;
        ctx.lineWidth = 3 * px;
        ctx.beginPath();
        ctx.arc(a[i * 6], a[i * 6 + 1], h.types[typeOf(i)].radius * 1.6 + 4 * px, 0, 2 * Math.PI);
        ctx.stroke();
      }
    }
    ctx.restore();
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

  let fpsCount = 0, fpsSince = performance.now(), plotsAt = 0;
  function animate(now) {
    if (replayData) replayTick(now);
    if (dirty) {
      dirty = false;
      draw();
      state.framesDrawn += 1;
      fpsCount += 1;
    }
    if (now - fpsSince >= 1000) {
      state.fps = (fpsCount * 1000) / (now - fpsSince);
      fpsCount = 0;
      fpsSince = now;
      $("fps-label").textContent = `${state.fps.toFixed(1)} fps`;
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

  function setupLive() {
    socket = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
    socket.binaryType = "arraybuffer";
    socket.onopen = () => { state.connected = true; send(Object.assign({ type: "overlays" }, state.overlays)); };
    socket.onclose = () => { state.connected = false; $("step-label").textContent = "disconnected from the server"; };
    socket.onmessage = (event) => {
      if (event.data instanceof ArrayBuffer) { receive(decode(event.data)); return; }
      const message = JSON.parse(event.data);
      if (message.type === "error") showError(message.message);
      else if (message.type === "notice") $("notice").textContent = message.message;
      else if (message.type === "hello") fillChoices(message.choices);
    };
    $("play").addEventListener("click", () => {
      send({ type: state.frame && state.frame.header.playing ? "pause" : "play" });
    });
    $("step").addEventListener("click", () => send({ type: "step" }));
    $("reset").addEventListener("click", () => send({ type: "reset" }));
    $("speed").addEventListener("change", (event) => send({ type: "speed", value: Number(event.target.value) }));
    $("world-index").addEventListener("change", (event) => send({ type: "world", index: Number(event.target.value) }));
    $("human").addEventListener("change", (event) => { send({ type: "human", team: event.target.value || null }); canvas.focus(); });
    $("record").addEventListener("click", () => send({ type: "record", on: !(state.frame && state.frame.header.recording) }));
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
  if (replayData) setupReplay(); else setupLive();
  requestAnimationFrame(animate);
})();
