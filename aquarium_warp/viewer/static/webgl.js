// The viewer's WebGL2 drawing of the agents (viewer.js uses it when the browser offers WebGL2, else draws
// everything with Canvas 2D). One instanced draw per type and layer: each agent, and each copy of it
// across the torus' seam, is a quad around it; the fragment shader decides which part of the fish or
// shark (kernels/render.py prey_part, predator_part) covers each of 2 x 2 samples of a pixel, or which
// zoomed-out mark (viewer.js markOf), or whether the pixel lies in the view cone.
"use strict";
window.AquariumGL = (function () {
  const VERTEX = `#version 300 es
layout(location = 0) in vec2 corner;  // the quad's corner, -1 or 1 each way
layout(location = 1) in vec3 agent;   // x, y (world px), heading angle (rad)
uniform vec3 view;       // the world point at the canvas' top-left (px), canvas pixels per world px
uniform vec2 canvasSize; // canvas pixels
uniform float extent;    // the quad's half size, world px
uniform float unit;      // world px per unit of 'local'
uniform bool upright;    // marks stay upright; shapes and cones turn with the heading
uniform bool points;     // one point (a square of 2 extent) per agent, not a quad
out vec2 local;          // where the fragment lies from the agent, u along the heading and v across
void main() {
  if (points) {
    gl_Position = vec4((agent.xy - view.xy) * view.z / canvasSize * vec2(2.0, -2.0) + vec2(-1.0, 1.0), 0.0, 1.0);
    gl_PointSize = 2.0 * extent * view.z;
    return;
  }
  vec2 h = upright ? vec2(1.0, 0.0) : vec2(cos(agent.z), sin(agent.z));
  vec2 d = corner * extent;
  vec2 world = agent.xy + vec2(d.x * h.x - d.y * h.y, d.x * h.y + d.y * h.x);
  vec2 pixel = (world - view.xy) * view.z;
  gl_Position = vec4(pixel / canvasSize * vec2(2.0, -2.0) + vec2(-1.0, 1.0), 0.0, 1.0);
  local = d / unit;
}`;

  // Modes: what the quads of one draw are, each a program of its own (a software GPU runs every branch
  // of a shader). Parts as in kernels/render.py (0: none; colours[part]).
  const MODES = ["cone", "fish", "shark", "oval", "dot", "diamond"];
  const FRAGMENT = `
precision highp float;
in vec2 local;
uniform float edge;        // outline thickness, in units of 'local'
uniform vec2 cone;         // the cone's radius (world px) and cos(fov / 2) (-2: a full disc)
uniform vec4 colours[6];   // premultiplied: cone, body, fin, eye, outline, stripe
out vec4 colour;

bool inEllipse(float u, float v, float cu, float a, float b) {
  float du = (u - cu) / a, dv = v / b;
  return du * du + dv * dv <= 1.0;
}
float side(vec2 p, vec2 a, vec2 b) { return (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x); }
bool inTriangle(vec2 p, vec2 a, vec2 b, vec2 c) {
  float s0 = side(p, a, b), s1 = side(p, b, c), s2 = side(p, c, a);
  return (s0 >= 0.0 && s1 >= 0.0 && s2 >= 0.0) || (s0 <= 0.0 && s1 <= 0.0 && s2 <= 0.0);
}
int fish(float u, float v) {
  float av = abs(v);
  vec2 q = vec2(u, av);
  float du = u - 0.4, dv = av - 0.14;
  if (du * du + dv * dv <= 0.07 * 0.07) return 3;
  if (inEllipse(u, av, 0.14, 0.56, 0.3)) {
    return inEllipse(u, av, 0.14, max(0.56 - edge, 1e-3), max(0.3 - edge, 1e-3)) ? 1 : 4;
  }
  if (inTriangle(q, vec2(-0.3, 0.0), vec2(-0.3, 0.17), vec2(-0.66, 0.07)) || (u >= -0.66 && u <= -0.3 && av <= 0.07)) return 1;
  if (inTriangle(q, vec2(-0.6, 0.0), vec2(-0.95, 0.34), vec2(-0.95, 0.0))
      && !inTriangle(q, vec2(-0.82, 0.0), vec2(-0.96, 0.14), vec2(-0.96, 0.0))) return 2;
  if (inTriangle(q, vec2(0.18, 0.24), vec2(-0.06, 0.27), vec2(-0.16, 0.46))) return 2;
  return 0;
}
int shark(float u, float v) {
  float av = abs(v);
  vec2 q = vec2(u, av);
  float du = u - 0.56, dv = av - 0.1;
  if (du * du + dv * dv <= 0.035 * 0.035) return 3;
  float half_ = u > 0.3 ? 0.23 * (1.0 - 0.45 * (u - 0.3) / 0.6) : 0.23;
  if (inEllipse(u, av, 0.05, 0.85, half_)) {
    if (!inEllipse(u, av, 0.05, max(0.85 - edge, 1e-3), max(half_ - edge, 1e-3))) return 4;
    if (inTriangle(q, vec2(0.18, 0.0), vec2(-0.12, 0.07), vec2(-0.3, 0.0))) return 5;
    return 1;
  }
  if (inTriangle(q, vec2(0.34, 0.15), vec2(-0.06, 0.2), vec2(-0.2, 0.6))) return 2;
  if (inTriangle(q, vec2(-0.6, 0.07), vec2(-0.96, 0.28), vec2(-0.8, 0.0))) return 2;
  return 0;
}
int part(vec2 p) {
#if MODE == 1
  return fish(p.x, p.y);
#elif MODE == 2
  return shark(p.x, p.y);
#else
  return inEllipse(p.x, p.y, -0.1, 0.9, 0.4) ? 1 : 0;
#endif
}
void main() {
#if MODE == 0  // the view cone's sector
  float dist = length(local);
  if (dist > cone.x || local.x < cone.y * dist) discard;
  colour = colours[0];
#elif MODE == 4  // a dot: the quad is the 3 x 3 canvas pixel square
  colour = colours[1];
#elif MODE == 5  // a diamond of 4 canvas pixels with an outline of one, in a point of 9.4
  vec2 d = (2.0 * gl_PointCoord - 1.0) * 4.7;
  float l1 = abs(d.x) + abs(d.y);
  if (l1 > 4.7) discard;
  colour = l1 <= 3.3 ? colours[1] : colours[4];
#else  // the 2 x 2 samples of the MP4's rasteriser: each covered one adds its part's colour
  vec2 dx = 0.25 * dFdx(local), dy = 0.25 * dFdy(local);
  vec4 sum = vec4(0.0);
  for (int k = 0; k < 4; k++) {
    int p = part(local + (k % 2 == 0 ? -dx : dx) + (k < 2 ? -dy : dy));
    if (p > 0) sum += colours[p];
  }
  if (sum.a == 0.0) discard;
  colour = 0.25 * sum;
#endif
}`;

  function compile(gl, type, source) {
    const shader = gl.createShader(type);
    gl.shaderSource(shader, source);
    gl.compileShader(shader);
    if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(shader));
    return shader;
  }

  // "#rrggbb" or "rgba(r,g,b,a)" -> premultiplied [r, g, b, a] in 0..1
  function rgba(css) {
    let r, g, b, a = 1;
    if (css[0] === "#") {
      [r, g, b] = [1, 3, 5].map((i) => parseInt(css.slice(i, i + 2), 16));
    } else {
      [r, g, b, a] = css.slice(css.indexOf("(") + 1, -1).split(",").map(Number);
    }
    return [(r / 255) * a, (g / 255) * a, (b / 255) * a, a];
  }

  // The renderer of `canvas`, or null when the browser offers no WebGL2 (or it fails to set up).
  function create(canvas, COLOURS) {
    const gl = canvas.getContext("webgl2", { antialias: false, alpha: false, preserveDrawingBuffer: false });
    if (!gl) return null;
    const programs = {};  // mode -> {program, at: its uniforms' locations}
    try {
      const vertex = compile(gl, gl.VERTEX_SHADER, VERTEX);
      MODES.forEach((mode, index) => {
        const program = gl.createProgram();
        gl.attachShader(program, vertex);
        gl.attachShader(program, compile(gl, gl.FRAGMENT_SHADER, `#version 300 es\n#define MODE ${index}\n${FRAGMENT}`));
        gl.linkProgram(program);
        if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
        const at = {};
        for (const name of ["view", "canvasSize", "extent", "unit", "upright", "points", "edge", "cone", "colours"]) {
          at[name] = gl.getUniformLocation(program, name);
        }
        programs[mode] = { program, at };
      });
    } catch (error) {
      console.warn("aquarium viewer: WebGL2 shaders failed, drawing with Canvas 2D:", error);
      return null;
    }
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    gl.bindBuffer(gl.ARRAY_BUFFER, gl.createBuffer());
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]), gl.STATIC_DRAW);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
    const instances = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, instances);
    gl.enableVertexAttribArray(1);
    gl.vertexAttribDivisor(1, 1);
    const pointsVao = gl.createVertexArray();  // the same buffer, one vertex per agent
    gl.bindVertexArray(pointsVao);
    gl.bindBuffer(gl.ARRAY_BUFFER, instances);
    gl.enableVertexAttribArray(1);
    const colour = (names) => new Float32Array(names.flatMap((name) => (name ? rgba(COLOURS[name]) : [0, 0, 0, 0])));
    const palette = {
      prey: colour(["preyCone", "prey", "preyFin", "preyEye", "preyEdge", null]),
      predator: colour(["predatorCone", "predator", "predatorFin", "predatorEye", "predatorEdge", "predatorStripe"]),
      predatorMark: colour([null, "predator", null, null, "predatorMarkEdge", null]),
    };
    const sea = rgba(COLOURS.sea), background = rgba(COLOURS.background);
    let built = null;  // the frame and reaches the instance buffer holds
    let data = { prey: new Float32Array(0), predator: new Float32Array(0) };
    const counts = { prey: 0, predator: 0 };

    // each agent as x, y, angle per type, with its copies across the seam whose disc of radius
    // reach[type] touches the world (viewer.js copies())
    function build(frame, reach) {
      if (built && built.frame === frame && built.prey === reach.prey && built.predator === reach.predator) return;
      const h = frame.header, n = h.n, W = h.width, H = h.height;
      const sx = W / 65536, sy = H / 65536, sa = (2 * Math.PI) / 65536;
      for (const type of ["prey", "predator"]) {
        if (data[type].length < 3 * n) data[type] = new Float32Array(Math.max(3 * n, 2 * data[type].length));
        counts[type] = 0;
      }
      const push = (type, x, y, angle) => {
        let d = data[type];
        if (3 * counts[type] + 3 > d.length) {
          data[type] = new Float32Array(2 * d.length + 48);
          data[type].set(d);
          d = data[type];
        }
        const k = 3 * counts[type]++;
        d[k] = x; d[k + 1] = y; d[k + 2] = angle;
      };
      const pos = frame.position, angles = frame.angle, slots = frame.slots;
      for (let i = 0; i < n; i++) {
        const type = slots[i] < h.prey_capacity ? "prey" : "predator", r = reach[type];
        const x = pos[2 * i] * sx, y = pos[2 * i + 1] * sy, angle = angles[i] * sa;
        push(type, x, y, angle);
        if (x >= r && x <= W - r && y >= r && y <= H - r) continue;  // no copy reaches the world
        for (let ox = -W; ox <= W; ox += W) {
          const cx = x + ox;
          if (cx + r < 0 || cx - r > W) continue;
          for (let oy = -H; oy <= H; oy += H) {
            const cy = y + oy;
            if ((ox !== 0 || oy !== 0) && cy + r >= 0 && cy - r <= H) push(type, cx, cy, angle);
          }
        }
      }
      gl.bindBuffer(gl.ARRAY_BUFFER, instances);
      gl.bufferData(gl.ARRAY_BUFFER, 12 * (counts.prey + counts.predator), gl.STREAM_DRAW);
      gl.bufferSubData(gl.ARRAY_BUFFER, 0, data.prey, 0, 3 * counts.prey);
      gl.bufferSubData(gl.ARRAY_BUFFER, 12 * counts.prey, data.predator, 0, 3 * counts.predator);
      built = { frame, prey: reach.prey, predator: reach.predator };
    }

    function instancesOf(type) {
      gl.bindBuffer(gl.ARRAY_BUFFER, instances);
      gl.vertexAttribPointer(1, 3, gl.FLOAT, false, 0, type === "prey" ? 0 : 12 * counts.prey);
      return counts[type];
    }

    // The sea, the view cones (with `cones`) and the bodies of `frame` under view `v`; `markOf(type, r,
    // px)` says how a type is drawn at this zoom ("shape", "oval", "dot" or "diamond").
    function draw(frame, v, cones, markOf) {
      gl.viewport(0, 0, canvas.width, canvas.height);
      gl.disable(gl.SCISSOR_TEST);
      gl.clearColor(...background);
      gl.clear(gl.COLOR_BUFFER_BIT);
      if (!frame || !v) return;
      const h = frame.header, W = h.width, H = h.height, px = 1 / v.scale;
      // the world's rectangle: the sea, and the clip of everything drawn in it
      const left = Math.round(-v.x * v.scale), right = Math.round((W - v.x) * v.scale);
      const top = Math.round(-v.y * v.scale), bottom = Math.round((H - v.y) * v.scale);
      gl.enable(gl.SCISSOR_TEST);
      gl.scissor(left, canvas.height - bottom, Math.max(0, right - left), Math.max(0, bottom - top));
      gl.clearColor(...sea);
      gl.clear(gl.COLOR_BUFFER_BIT);
      const halfDiagonal = 0.5 * Math.hypot(W, H);
      const marks = {}, bodyReach = {}, reach = {};
      for (const type of ["prey", "predator"]) {
        const t = h.types[type];
        marks[type] = markOf(type, t.radius, px);
        bodyReach[type] = marks[type] === "shape" || marks[type] === "oval" ? t.radius : 4.7 * px;  // as drawAll's
        reach[type] = Math.max(bodyReach[type], cones ? Math.min(t.view_distance, halfDiagonal) : 0);
      }
      build(frame, reach);
      gl.bindVertexArray(vao);
      gl.enable(gl.BLEND);
      gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);  // premultiplied colours
      // one instanced draw of a type's agents in `mode`: quads of half size `extent` (world px), their
      // 'local' in units of `unit` world px
      const drawAll = (type, mode, extent, unit, colours, more) => {
        const { program, at } = programs[mode];
        gl.useProgram(program);
        gl.uniform3f(at.view, v.x, v.y, v.scale);
        gl.uniform2f(at.canvasSize, canvas.width, canvas.height);
        gl.uniform1f(at.extent, extent);
        gl.uniform1f(at.unit, unit);
        const points = mode === "dot" || mode === "diamond";  // upright marks: points, cheaper than quads
        gl.uniform1i(at.upright, points ? 1 : 0);
        gl.uniform1i(at.points, points ? 1 : 0);
        gl.uniform4fv(at.colours, colours);
        if (more) more(at);
        gl.bindVertexArray(points ? pointsVao : vao);
        if (points) gl.drawArrays(gl.POINTS, 0, instancesOf(type));
        else gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, instancesOf(type));
      };
      if (cones) {
        for (const type of ["prey", "predator"]) {
          const t = h.types[type], r = Math.min(t.view_distance, halfDiagonal);
          const cosHalf = t.fov < 360 ? Math.cos(((t.fov / 2) * Math.PI) / 180) : -2;
          drawAll(type, "cone", r, 1, palette[type], (at) => gl.uniform2f(at.cone, r, cosHalf));
        }
      }
      for (const type of ["prey", "predator"]) {
        const r = h.types[type].radius, mark = marks[type];
        if (mark === "shape") {
          drawAll(type, type === "prey" ? "fish" : "shark", r, r, palette[type], (at) => gl.uniform1f(at.edge, px / r));
        } else if (mark === "oval") {
          drawAll(type, "oval", r, r, palette[type]);
        } else {
          drawAll(type, mark, (mark === "dot" ? 1.5 : 4.7) * px, px, mark === "diamond" ? palette.predatorMark : palette[type]);
        }
      }
      gl.disable(gl.BLEND);
    }

    // RGB of canvas pixel (column, row from the top) as last drawn: call right after `draw`
    function pixel(column, row) {
      const out = new Uint8Array(4);
      gl.readPixels(column, canvas.height - 1 - row, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, out);
      return Array.from(out.slice(0, 3));
    }

    const info = gl.getExtension("WEBGL_debug_renderer_info");
    const name = info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
    return { draw, pixel, name, lost: () => gl.isContextLost() };
  }

  return { create };
})();
