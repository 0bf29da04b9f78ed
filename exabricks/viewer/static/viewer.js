// exabricks view: the page. It edits a scene file's object (docs/scene.md) and sends
// it to the server, which streams progressive frames back (exabricks/viewer/page.py).
// The same code runs on `exabricks view`'s page, over a websocket (socketChannel), and
// in a notebook's output cell, over the widget's comm (widgetChannel,
// exabricks/viewer/notebook.py): exabricksViewer(root, channel) is one viewer in `root`.
"use strict";

const WHEEL_SETTLE_MS = 200;  // no wheel event for this long: the zoom has stopped
const AXES = ["x", "y", "z"];

// ---------------------------------------------------------------- vectors
const sub = (a, b) => a.map((x, i) => x - b[i]);
const add = (a, b) => a.map((x, i) => x + b[i]);
const mul = (a, s) => a.map((x) => x * s);
const dot = (a, b) => a.reduce((s, x, i) => s + x * b[i], 0);
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => Math.hypot(...a);
const unit = (a) => mul(a, 1 / (norm(a) || 1));
function rotate(v, axis, angle) {  // Rodrigues
  const k = unit(axis), c = Math.cos(angle), s = Math.sin(angle);
  return add(add(mul(v, c), mul(cross(k, v), s)), mul(k, dot(k, v) * (1 - c)));
}

// ---------------------------------------------------------------- the channels
// A channel takes the viewer's handlers (text: a JSON message, binary: a frame's PNG
// blob, closed: a line to show) and gives back { send(text) }.
function socketChannel(on) {
  // beside the page, wherever it is served (a proxy's prefix, https)
  const url = new URL("ws", location.href);
  url.protocol = location.protocol === "https:" ? "wss:" : "ws:";
  url.search = "";
  const ws = new WebSocket(url);
  ws.binaryType = "blob";
  ws.onmessage = (event) => (typeof event.data === "string" ? on.text(event.data) : on.binary(event.data));
  ws.onclose = () => on.closed("disconnected: is `exabricks view` still running?");
  return { send: (text) => ws.send(text), close: () => ws.close() };
}

// A notebook widget's comm (anywidget's model): each message is { text } or, for a
// frame's PNG, { binary: true } with the PNG as its buffer. "hello" asks the kernel
// for the "init" message and the current frame, as a websocket's opening does;
// "bye", when the view goes, lets the kernel free what draws when none is left.
function widgetChannel(model) {
  return (on) => {
    const handler = (msg, buffers) => {
      if (msg.binary) on.binary(new Blob([buffers[0]], { type: "image/png" }));
      else on.text(msg.text);
    };
    model.on("msg:custom", handler);
    model.send({ text: JSON.stringify({ type: "hello" }) });
    const close = () => {
      model.off("msg:custom", handler);
      // a widget closed in the kernel has no comm left to say it on
      try { model.send({ text: JSON.stringify({ type: "bye" }) }); } catch (e) { /* closed */ }
    };
    return { send: (text) => model.send({ text }), close };
  };
}

function exabricksViewer(root, channel) {
  const $ = (id) => root.querySelector(`#${id}`);
  const state = { doc: null, info: null, start: null, channel: null, pending: null, version: 0,
                  frame: null, url: null, moving: false, layer: null, sent: null, latency: [] };

  function connect() {
    let header = null;
    state.channel = channel({
      text: (text) => {
        const msg = JSON.parse(text);
        if (msg.type === "init") init(msg);
        else if (msg.type === "frame") header = msg;
        else if (msg.type === "saved") saved(msg);
        else if (msg.type === "error") error(msg.message);
        else if (msg.type === "status") waiting(msg.line);
      },
      binary: (blob) => {
        if (header) show(header, blob);
        header = null;
      },
      closed: (line) => { $("status").textContent = line; },
    });
  }

  function send(moving = false) {
    state.moving = moving;
    if (state.pending) return;
    state.pending = requestAnimationFrame(() => {  // one message per animation frame at most
      state.pending = null;
      state.version += 1;
      state.sent = [state.version, performance.now()];
      state.channel.send(JSON.stringify({ type: "scene", scene: state.doc, version: state.version,
                                     moving: state.moving && $("lod-moving").checked }));
    });
  }

  function show(h, blob) {
    if (state.url) URL.revokeObjectURL(state.url);
    state.url = URL.createObjectURL(blob);
    state.blob = blob;  // the PNG shown
    // every stage at the scene's whole size (within the view): a preview is a blurry
    // picture of the same size, not a small one
    const [width, height] = h.size || [h.width, h.height], img = $("frame");
    img.style.width = `${width}px`;
    img.style.height = `${height}px`;
    img.src = state.url;
    state.frame = h;
    // each stage's time since the change was sent, and the time the server took to draw it
  // (the last 100 frames; for the benchmarks)
    if (state.sent && state.sent[0] === h.version) {
      state.latency.push({ version: h.version, stage: h.stage, ms: performance.now() - state.sent[1], drawn: h.ms });
      if (state.latency.length > 100) state.latency.shift();
    }
    // the key light this frame was lit by becomes the scene's own: it stays fixed in
    // the world as the camera moves (docs/view.md, "Lights")
    if (h.key_light && !(state.doc.lighting.light || {}).direction) {
      state.doc.lighting.light = { ...(state.doc.lighting.light || {}), direction: h.key_light };
      AXES.forEach((a, i) => { $(`light-${a}`).value = h.key_light[i]; });
    }
    if (h.layer) {
      state.layer = h.layer;
      if (!explicit(volume())) { drawOpacity(); rangeInputs(); }
    }
    $("error").hidden = true;
    const rate = h.samples_per_second ? `${(h.samples_per_second / 1e6).toFixed(1)} M samples/s` : "";
    $("status").textContent = `${h.stage} ${h.width}×${h.height}, ${h.spp} spp, ${h.ms} ms, ${rate} on ${h.device}`;
    $("status").dataset.stage = h.stage;
  }

  // What the frame under way waits for (a kernel build: seconds, once per machine).
  function waiting(line) {
    $("status").textContent = line;
    $("status").dataset.stage = "waiting";
  }

  function error(message) {
    $("error").textContent = message;
    $("error").hidden = false;
  }

  // ---------------------------------------------------------------- start
  function init(msg) {
    state.info = msg;
    state.doc = msg.scene;
    state.start = JSON.parse(JSON.stringify(msg.scene));
    const fields = Object.keys(msg.fields);
    $("field").replaceChildren(...fields.map((f) => new Option(f, f)));
    $("colormap").replaceChildren(...msg.colormaps.map((c) => new Option(c, c)));
    $("integrator").replaceChildren(...msg.integrators.map((i) => new Option(i, i)));
    fill();
    if (!state.frame) waiting("drawing the first frame…");
  }

  // The first volume layer (the automatic one, as `render` draws it, where there is none).
  // Its transfer function is left as the document has it: a colour map with opacity
  // knots, a colour map alone (the automatic opacity), or a preset.
  function volume() {
    if (!state.doc.volumes.length) {
      state.doc.volumes.push({ field: Object.keys(state.info.fields)[0], transfer_function: { colormap: "viridis" } });
    }
    const v = state.doc.volumes[0];
    if (v.transfer_function === undefined) v.transfer_function = { colormap: "viridis" };
    return v;
  }

  // The layer's colour map: a name, or "" for a preset.
  function colormapOf(v) {
    const tf = v.transfer_function;
    return (typeof tf === "object" && tf !== null && typeof tf.colormap === "string" && tf.colormap) || "";
  }

  // Whether the layer has opacity knots of its own (else the editor shows those the
  // server sampled from the function it drew: state.layer).
  function explicit(v) {
    return !!colormapOf(v) && Array.isArray(v.transfer_function.opacity);
  }

  // The layer's opacity knots and the range they span, as the editor shows them; null
  // before the server has said what a layer without knots draws.
  function shownKnots(v) {
    if (explicit(v)) return { knots: v.transfer_function.opacity, range: v.range || fieldRange(v.field) };
    const l = state.layer;
    return l && l.field === v.field ? { knots: l.opacity, range: l.range } : null;
  }

  // Make the layer's knots its own, starting from those shown (the automatic function's,
  // sampled over its colours' span on its scale): what the user then edits.
  function editable(v, colormap) {
    if (explicit(v)) return true;
    const l = state.layer;
    if (!l || l.field !== v.field) return false;
    v.transfer_function = { colormap: colormap || colormapOf(v) || "viridis", opacity: l.opacity.slice() };
    v.range = l.range.slice();
    v.scale = l.scale;
    return true;
  }

  // A field's range, or [0, 1] for a name the data lacks (the server then says so).
  function fieldRange(name) {
    const f = state.info.fields[name];
    return f ? f.range.slice() : [0, 1];
  }

  // Every control from the document.
  function fill() {
    const d = state.doc, v = volume();
    $("field").value = v.field;
    const name = colormapName(v);
    if (![...$("colormap").options].some((o) => o.value === name)) $("colormap").add(new Option(name, name));
    $("colormap").value = name;
    rangeInputs();
    $("shading").value = d.lighting.shading;
    $("ao").value = (d.lighting.ambient_occlusion || {}).samples || 0;
    $("integrator").value = d.lighting.integrator || "headlight";
    const toward = (d.lighting.light || {}).direction;  // none: the camera's key light
    AXES.forEach((a, i) => { $(`light-${a}`).value = toward ? toward[i] : ""; });
    $("ambient").value = d.lighting.ambient ?? "";  // none: the scene's default
    $("bounces").value = (d.lighting.path || {}).bounces ?? "";
    $("anisotropy").value = (d.lighting.path || {}).anisotropy ?? "";
    $("background").value = "#" + d.background.slice(0, 3).map((c) => Math.round(c * 255).toString(16).padStart(2, "0")).join("");
    $("reconstruction").value = d.reconstruction;
    $("width").value = d.size[0];
    $("height").value = d.size[1];
    $("spp").value = d.spp;
    const lo = state.info.bounds[0], hi = state.info.bounds[1];
    const box = d.clip.box || [...lo, ...hi];
    $("clip-box-on").checked = !!d.clip.box;
    numbers("clip-box", box, (values) => { d.clip.box = values; }, () => $("clip-box-on").checked);
    const plane = (d.clip.planes && d.clip.planes[0]) || [...mul(add(lo, hi), 0.5), 0, 0, 1];
    $("clip-plane-on").checked = !!(d.clip.planes && d.clip.planes.length);
    numbers("clip-plane", plane, (values) => { d.clip.planes = [values]; }, () => $("clip-plane-on").checked);
    isos();
    slices();
    drawOpacity();
  }

  // The colour map's name, or a preset's ("preset NAME"), for the colour-map list.
  function colormapName(v) {
    const tf = v.transfer_function;
    if (typeof tf !== "object" || tf === null) return `preset ${tf}`;
    return colormapOf(v) || `preset ${tf.Name || "inline"}`;
  }

  // The range boxes: the layer's range, else the span the server drew it over.
  function rangeInputs() {
    const v = volume(), shown = shownKnots(v);
    const range = v.range || (shown && shown.range) || fieldRange(v.field);
    for (const [i, id] of [[0, "range-lo"], [1, "range-hi"]]) {
      if (document.activeElement !== $(id)) $(id).value = range[i];
    }
  }

  function numbers(id, values, set, enabled) {
    const inputs = values.map((x) => {
      const input = document.createElement("input");
      input.type = "number"; input.step = "any"; input.value = +x.toPrecision(6);
      input.onchange = () => { if (enabled()) { set(inputs.map((i) => +i.value)); send(); } };
      return input;
    });
    $(id).replaceChildren(...inputs);
  }

  // ---------------------------------------------------------------- opacity editor
  function drawOpacity() {
    const c = $("opacity"), g = c.getContext("2d"), v = volume();
    // the field's histogram (log counts) under the knots, over the layer's range
    const field = state.info.fields[v.field] || { histogram: [], range: fieldRange(v.field) };
    const shown = shownKnots(v);
    const hist = field.histogram, top = Math.log1p(Math.max(...hist, 1));
    const [flo, fhi] = field.range, [rlo, rhi] = shown ? shown.range : fieldRange(v.field);
    const bin = (fhi - flo) / hist.length;
    const x = (value) => 5 + ((value - rlo) / ((rhi - rlo) || 1)) * (c.width - 10);
    g.clearRect(0, 0, c.width, c.height);
    g.fillStyle = "#3a4150";
    hist.forEach((n, i) => {
      const h = (Math.log1p(n) / top) * (c.height - 10), x0 = x(flo + i * bin), x1 = x(flo + (i + 1) * bin);
      if (x1 > 0 && x0 < c.width) g.fillRect(x0, c.height - h, Math.max(1, x1 - x0 - 1), h);
    });
    if (!shown) return;
    const knots = shown.knots;
    if (!explicit(v)) {  // the automatic function (or a preset), until a knot is touched
      g.fillStyle = "#9aa0aa"; g.font = "11px system-ui, sans-serif";
      g.fillText(`${colormapOf(v) ? "automatic" : "preset"}: drag a knot to edit`, 10, 14);
    }
    g.strokeStyle = "#ffd166"; g.lineWidth = 2; g.beginPath();
    knots.forEach((a, i) => { const [x, y] = knotXY(i, knots.length, a); i ? g.lineTo(x, y) : g.moveTo(x, y); });
    g.stroke();
    g.fillStyle = "#ffd166";
    knots.forEach((a, i) => { const [x, y] = knotXY(i, knots.length, a); g.fillRect(x - 4, y - 4, 8, 8); });
  }

  function knotXY(i, n, a) {
    const c = $("opacity");
    return [5 + (i * (c.width - 10)) / Math.max(1, n - 1), 5 + (1 - a) * (c.height - 10)];
  }

  function opacityEditor() {
    const c = $("opacity");
    let knot = -1;
    const alphaAt = (e) => {
      const r = c.getBoundingClientRect(), y = ((e.clientY - r.top) * c.height) / r.height;
      return Math.min(1, Math.max(0, 1 - (y - 5) / (c.height - 10)));
    };
    c.addEventListener("pointerdown", (e) => {
      const r = c.getBoundingClientRect(), x = ((e.clientX - r.left) * c.width) / r.width;
      if (!editable(volume())) return;
      const knots = volume().transfer_function.opacity;
      let best = 1e9;
      knots.forEach((a, i) => { const d = Math.abs(knotXY(i, knots.length, a)[0] - x); if (d < best) { best = d; knot = i; } });
      c.setPointerCapture(e.pointerId);
      move(e);
    });
    const move = (e) => {
      if (knot < 0) return;
      volume().transfer_function.opacity[knot] = +alphaAt(e).toFixed(4);
      drawOpacity();
      send();
    };
    c.addEventListener("pointermove", move);
    c.addEventListener("pointerup", () => { knot = -1; });
    const resample = (n) => {
      if (!editable(volume())) return;
      const k = volume().transfer_function.opacity, out = [];
      for (let i = 0; i < n; i++) {
        const t = (i * (k.length - 1)) / Math.max(1, n - 1), j = Math.min(k.length - 2, Math.floor(t));
        out.push(k.length === 1 ? k[0] : +(k[j] + (k[j + 1] - k[j]) * (t - j)).toFixed(4));
      }
      volume().transfer_function.opacity = out;
      drawOpacity();
      send();
    };
    const count = () => (shownKnots(volume()) || { knots: [0, 1] }).knots.length;
    $("knot-more").onclick = () => resample(Math.min(32, count() + 1));
    $("knot-less").onclick = () => resample(Math.max(2, count() - 1));
  }

  // ---------------------------------------------------------------- iso-surfaces and slices
  function slider(value, lo, hi, onInput) {
    const range = document.createElement("input");
    range.type = "range"; range.min = lo; range.max = hi; range.step = (hi - lo) / 1000 || 1e-6;
    range.value = value;
    const box = document.createElement("input");
    box.type = "number"; box.step = "any"; box.value = +(+value).toPrecision(6);
    range.oninput = () => { box.value = +(+range.value).toPrecision(6); onInput(+range.value); };
    box.onchange = () => { range.value = box.value; onInput(+box.value); };
    return [range, box];
  }

  function removeButton(list, i, redraw) {
    const b = document.createElement("button");
    b.textContent = "×"; b.title = "remove";
    b.onclick = () => { list.splice(i, 1); redraw(); send(); };
    return b;
  }

  function isos() {
    const list = state.doc.isosurfaces;
    $("isos").replaceChildren(...list.map((iso, i) => {
      const row = document.createElement("div");
      row.className = "item iso";
      const [lo, hi] = fieldRange(iso.field);
      row.append(iso.field, ...slider(iso.value, lo, hi, (x) => { iso.value = x; send(); }),
                 removeButton(list, i, isos));
      return row;
    }));
  }

  function slices() {
    const list = state.doc.slices, [lo, hi] = state.info.bounds;
    $("slices").replaceChildren(...list.map((s, i) => {
      const row = document.createElement("div");
      row.className = "item slice";
      const axis = s.normal.findIndex((x) => Math.abs(x) === 1 && s.normal.filter((y) => y === 0).length === 2);
      if (axis < 0) { row.append("oblique slice", removeButton(list, i, slices)); return row; }
      row.append("xyz"[axis], ...slider(s.point[axis], lo[axis], hi[axis], (x) => { s.point[axis] = x; send(); }),
                 removeButton(list, i, slices));
      return row;
    }));
  }

  // ---------------------------------------------------------------- the camera
  function cameraControls() {
    const view = $("view");
    const pointers = new Map();
    let last = null, pinch = null, wheelTimer = null;
    view.addEventListener("contextmenu", (e) => e.preventDefault());
    view.addEventListener("pointerdown", (e) => {
      view.setPointerCapture(e.pointerId);
      pointers.set(e.pointerId, [e.clientX, e.clientY]);
      last = { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 || e.button === 1 };
      view.classList.add("dragging");
    });
    view.addEventListener("pointermove", (e) => {
      if (!pointers.has(e.pointerId)) return;
      pointers.set(e.pointerId, [e.clientX, e.clientY]);
      if (pointers.size === 2) {
        const [a, b] = [...pointers.values()], d = Math.hypot(a[0] - b[0], a[1] - b[1]);
        if (pinch) zoom(pinch / d);
        pinch = d;
        return;
      }
      const dx = e.clientX - last.x, dy = e.clientY - last.y;
      last.x = e.clientX; last.y = e.clientY;
      if (last.pan) pan(dx, dy); else orbit(dx, dy);
    });
    const up = (e) => {
      pointers.delete(e.pointerId);
      if (pointers.size < 2) pinch = null;
      if (!pointers.size) { view.classList.remove("dragging"); send(false); }
    };
    view.addEventListener("pointerup", up);
    view.addEventListener("pointercancel", up);
    view.addEventListener("wheel", (e) => {
      e.preventDefault();
      zoom(Math.exp(e.deltaY * 0.001));
      // a wheel has no "up": once it has been still a while, the zoom has stopped and the
      // frame refines to converged, as after a drag
      clearTimeout(wheelTimer);
      wheelTimer = setTimeout(() => { wheelTimer = null; send(false); }, WHEEL_SETTLE_MS);
    }, { passive: false });
    $("reset").onclick = () => { state.doc.camera = JSON.parse(JSON.stringify(state.start.camera)); send(); };
  }

  function orbit(dx, dy) {
    const c = state.doc.camera;
    let offset = sub(c.position, c.look_at);
    const up = unit(c.up), right = unit(cross(offset, up));
    offset = rotate(offset, up, -dx * 0.01);
    const turned = rotate(offset, right, dy * 0.01);
    if (Math.abs(dot(unit(turned), up)) < 0.995) offset = turned;  // not over the pole
    c.position = add(c.look_at, offset);
    send(true);
  }

  function pan(dx, dy) {
    const c = state.doc.camera, offset = sub(c.position, c.look_at);
    const dist = norm(offset), up = unit(c.up), right = unit(cross(up, offset));
    const scale = (2 * dist * Math.tan((c.fovy * Math.PI) / 360)) / ($("frame").clientHeight || 512);
    const shift = add(mul(right, -dx * scale), mul(unit(cross(offset, right)), -dy * scale));
    c.position = add(c.position, shift);
    c.look_at = add(c.look_at, shift);
    send(true);
  }

  function zoom(factor) {
    const c = state.doc.camera;
    c.position = add(c.look_at, mul(sub(c.position, c.look_at), factor));
    send(true);
  }

  // ---------------------------------------------------------------- the other controls
  function controls() {
    $("field").onchange = () => {
      const v = volume();
      v.field = $("field").value;
      if (explicit(v)) v.range = fieldRange(v.field);  // the knots over the new field's range
      else {  // the new field's automatic function, in the colour map chosen
        v.transfer_function = { colormap: colormapOf(v) || "viridis" };
        delete v.range;
      }
      delete v.scale;  // the new field's own (auto: log for a positive field over decades)
      fill(); send();
    };
    $("colormap").onchange = () => {
      const v = volume(), name = $("colormap").value;
      if (name.startsWith("preset ")) return;
      if (colormapOf(v)) v.transfer_function.colormap = name;  // automatic or knots: the colours only
      else if (!editable(v, name)) return;  // a preset: its opacity, in this colour map
      send();
    };
    $("range-lo").onchange = $("range-hi").onchange = () => {
      volume().range = [+$("range-lo").value, +$("range-hi").value]; drawOpacity(); send();
    };
    $("iso-add").onclick = () => {
      // where the surface shows: the server's suggested_iso_value of the field (the far side
      // of the ambient medium, e.g. a blast's shell), else mid-range
      const v = volume(), [lo, hi] = fieldRange(v.field), f = state.info.fields[v.field];
      const value = f && typeof f.iso === "number" ? f.iso : (lo + hi) / 2;
      state.doc.isosurfaces.push({ field: v.field, value, color: [0.9, 0.9, 0.9], opacity: 1 });
      isos(); send();
    };
    $("slice-add").onclick = () => {
      const v = volume(), [lo, hi] = state.info.bounds, shown = shownKnots(v);
      const colormap = colormapOf(v) || "viridis";
      state.doc.slices.push({ point: mul(add(lo, hi), 0.5), normal: [0, 1, 0], field: v.field, colormap,
                              range: (v.range || (shown && shown.range) || fieldRange(v.field)).slice() });
      slices(); send();
    };
    $("clip-box-on").onchange = () => {
      if ($("clip-box-on").checked) state.doc.clip.box = [...$("clip-box").children].map((i) => +i.value);
      else delete state.doc.clip.box;
      send();
    };
    $("clip-plane-on").onchange = () => {
      state.doc.clip.planes = $("clip-plane-on").checked ? [[...$("clip-plane").children].map((i) => +i.value)] : [];
      send();
    };
    $("shading").onchange = () => { state.doc.lighting.shading = $("shading").value; send(); };
    $("ao").onchange = () => {
      state.doc.lighting.ambient_occlusion = { ...(state.doc.lighting.ambient_occlusion || {}), samples: +$("ao").value };
      send();
    };
    $("background").oninput = () => {
      const h = $("background").value;
      state.doc.background = [1, 3, 5].map((i) => parseInt(h.slice(i, i + 2), 16) / 255).concat([1]);
      send();
    };
    $("integrator").onchange = () => { state.doc.lighting.integrator = $("integrator").value; send(); };
    AXES.forEach((a) => {
      $(`light-${a}`).onchange = () => {
        const light = { ...(state.doc.lighting.light || {}) }, given = AXES.map((b) => $(`light-${b}`).value);
        if (given.every((x) => x === "")) delete light.direction;
        else light.direction = given.map((x) => +x || 0);
        state.doc.lighting.light = light;
        send();
      };
    });
    $("ambient").onchange = () => { state.doc.lighting.ambient = Math.max(0, +$("ambient").value); send(); };
    ["bounces", "anisotropy"].forEach((key) => {
      $(key).onchange = () => {
        const path = { ...(state.doc.lighting.path || {}) }, v = $(key).value;
        if (v === "") delete path[key]; else path[key] = +v;
        state.doc.lighting.path = path;
        send();
      };
    });
    $("reconstruction").onchange = () => { state.doc.reconstruction = $("reconstruction").value; send(); };
    $("width").onchange = $("height").onchange = () => { state.doc.size = [+$("width").value, +$("height").value]; send(); };
    $("spp").onchange = () => { state.doc.spp = +$("spp").value; send(); };
    $("save").onclick = () => state.channel.send(JSON.stringify({ type: "save" }));
    $("load").onchange = async () => {
      const file = $("load").files[0];
      if (!file) return;
      try {
        state.doc = JSON.parse(await file.text());
      } catch (e) {
        error(`${file.name}: not a JSON scene file`);
        return;
      }
      for (const [k, v] of Object.entries({ volumes: [], isosurfaces: [], slices: [], clip: {}, lighting: { shading: "headlight" },
                                            background: [0, 0, 0, 0], size: state.start.size, spp: 1,
                                            reconstruction: "basis", camera: state.doc.camera || state.start.camera })) {
        if (state.doc[k] === undefined) state.doc[k] = v;
      }
      fill(); send();
    };
  }

  function saved(msg) {
    const blob = new Blob([JSON.stringify(msg.scene, null, 1) + "\n"], { type: "application/json" });
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = "scene.json";
    a.click();
    $("saved").textContent = msg.path ? `saved to ${msg.path} and downloaded` : "downloaded scene.json";
  }

  cameraControls();
  opacityEditor();
  controls();
  connect();
  state.close = () => state.channel.close();
  state.send = send;  // for the benchmarks: a change made to state.doc, drawn
  return state;
}

// `exabricks view`'s page (a module, the notebook widget, has no currentScript)
if (document.currentScript) window.exabricks = exabricksViewer(document, socketChannel);
