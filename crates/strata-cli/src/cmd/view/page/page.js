// strata view: the page. Plain JavaScript, no build step; served by `strata view`.
//
// The page owns the view (camera, size, method and options) and sends it whole on every change;
// the server renders the newest view it has and sends back a frame: a u32 little-endian header
// length, a JSON header (request id, `strata render --stats` statistics, the camera as scene-file
// lines) and a PNG. See crates/strata-cli/src/cmd/view/protocol.rs.
//
// With `strata view --mfr` (the hello says `mfr`) the page drives a multi-frame-rate session
// instead: it sends its settings as an "mfr" message and the pointer as "pointer" events; frames
// come at the fast client's pace with the clients' rates in `header.mfr` (see
// crates/strata-cli/src/cmd/view/mfr.rs).
//
// With `strata view --nodes …` (the hello says `remote`) the page is the display of render nodes:
// it sends its camera and size as a "remote" message, and frames come as the display composes
// them, with every node's status, figures and incidents in `header.remote` (see
// crates/strata-cli/src/cmd/view/remote.rs).
"use strict";

const $ = (id) => document.getElementById(id);

// Everything the page knows, exposed for people debugging and for the browser tests.
const S = {
  hello: null,          // the server's hello message
  camera: null,         // {eye, target, up, fovy_deg, near, far}, scene-file terms
  method: null,
  options: {},          // option name -> value string, only those set away from the default
  reference: null,      // the method compared with, or null
  referenceOptions: {},
  show: "side",         // with a reference: side, split, bad, flip, main or reference
  split: 0.5,
  animationFrame: 0,
  images: {},           // name -> ImageBitmap of the frame on the canvas
  nextId: 1,
  sent: new Map(),      // request id -> performance.now() when sent
  lastSentId: 0,
  frame: null,          // the header of the frame on the canvas
  framesShown: 0,
  shownTimes: [],       // when recent frames were shown, for the rate
  latencyMs: null,      // request sent -> its frame drawn, of the last frame
  errors: [],           // {id, message}
  pixel: null,          // the last pixel message: {frame, x, y, fragments}
  socket: null,
  connects: 0,
  // Multi-frame-rate mode: the settings sent, the pointer events sent (seq -> time) and the
  // latency from the newest pointer event a frame shows to that frame drawn.
  mfr: { composition: "deep", migration: "predictive", fc_hz: 30, sc_interval_ms: 0, audit: false },
  pointerSeq: 0,
  pointerSent: new Map(),
  pointerShown: null,
  pointerLatencyMs: null,
  // Remote mode: the display's settings beside the camera and size.
  remote: { max_fps: 30 },
};
window.strataView = S;

const canvas = $("frame");
const ctx = canvas.getContext("2d");
const fixedSize = (() => {
  const m = /^(\d+)x(\d+)$/.exec(new URLSearchParams(location.search).get("size") || "");
  return m ? [Number(m[1]), Number(m[2])] : null;
})();

// ---- vectors -------------------------------------------------------------------------------
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const len = (a) => Math.sqrt(dot(a, a));
const norm = (a) => scale(a, 1 / len(a));
// Rodrigues: v rotated by angle about the unit axis k.
const rotate = (v, k, angle) => {
  const c = Math.cos(angle), s = Math.sin(angle);
  return add(add(scale(v, c), scale(cross(k, v), s)), scale(k, dot(k, v) * (1 - c)));
};

// ---- navigation ----------------------------------------------------------------------------
function orbit(dx, dy) {
  const c = S.camera;
  const up = norm(c.up);
  let offset = sub(c.eye, c.target);
  offset = rotate(offset, up, -dx * 0.008);
  const right = norm(cross(up, offset));
  // Pitch, stopping short of the poles so that up never becomes parallel to the view.
  const polar = Math.acos(Math.max(-1, Math.min(1, dot(norm(offset), up))));
  const limit = 0.02;
  const pitch = Math.max(polar - (Math.PI - limit), Math.min(polar - limit, -dy * 0.008));
  offset = rotate(offset, right, pitch);
  c.eye = add(c.target, offset);
}

function pan(dx, dy) {
  const c = S.camera;
  const offset = sub(c.eye, c.target);
  const forward = norm(scale(offset, -1));
  const right = norm(cross(forward, c.up));
  const upv = cross(right, forward);
  const h = canvas.clientHeight || 1;
  const perPixel = (2 * len(offset) * Math.tan((c.fovy_deg * Math.PI) / 360)) / h;
  const move = add(scale(right, -dx * perPixel), scale(upv, dy * perPixel));
  c.eye = add(c.eye, move);
  c.target = add(c.target, move);
}

function zoom(factor) {
  const c = S.camera;
  const offset = sub(c.eye, c.target);
  const d = len(offset);
  const next = Math.min(c.far * 0.9, Math.max(c.near * 2, d * factor));
  c.eye = add(c.target, scale(offset, next / d));
}

const isMfr = () => Boolean(S.hello && S.hello.mfr);
const isRemote = () => Boolean(S.hello && S.hello.remote);

// Multi-frame rate: the pointer as the session sees it. Moves are coalesced to one event per
// animation frame (the newest position); presses and releases go at once, after it.
let pointerPending = null;
let pointerScheduled = false;
let pointerLast = null;
function sendPointer(e, pressed, now) {
  // A release outside the frame still releases, where the pointer last was on it.
  const at = framePoint(e) || (!pressed && pointerLast);
  if (!at) return;
  pointerLast = at;
  pointerPending = { x: at[0], y: at[1], pressed };
  if (now) flushPointer();
  else if (!pointerScheduled) {
    pointerScheduled = true;
    requestAnimationFrame(() => { pointerScheduled = false; flushPointer(); });
  }
}
function flushPointer() {
  if (!pointerPending || !S.socket || S.socket.readyState !== WebSocket.OPEN) return;
  const seq = ++S.pointerSeq;
  S.pointerSent.set(seq, performance.now());
  if (S.pointerSent.size > 512) S.pointerSent.delete(S.pointerSent.keys().next().value);
  S.socket.send(JSON.stringify({ type: "pointer", ...pointerPending, seq }));
  pointerPending = null;
}

const pointers = new Map(); // pointerId -> {x, y}
canvas.addEventListener("contextmenu", (e) => e.preventDefault());
canvas.addEventListener("pointerdown", (e) => {
  if (!S.camera) return;
  canvas.setPointerCapture(e.pointerId);
  // In multi-frame-rate mode a left press on an object the session has under the pointer
  // (OVER) grabs it; anywhere else it orbits, pans or zooms as always.
  const grab = isMfr() && e.button === 0 && !e.shiftKey && pointers.size === 0
    && Boolean(S.frame && S.frame.mfr && S.frame.mfr.over);
  pointers.set(e.pointerId, {
    x: e.clientX, y: e.clientY, x0: e.clientX, y0: e.clientY, moved: false,
    button: e.button, shift: e.shiftKey, grab,
  });
  if (grab) sendPointer(e, true, true);
  canvas.classList.add("dragging");
});
canvas.addEventListener("pointermove", (e) => {
  const p = pointers.get(e.pointerId);
  if (isMfr() && (!p || p.grab)) {
    sendPointer(e, Boolean(p), false);
    return;
  }
  if (!p || !S.camera) return;
  // A press that moves less than a few pixels is a click (inspect), not a drag.
  if (!p.moved && Math.hypot(e.clientX - p.x0, e.clientY - p.y0) < 4) return;
  p.moved = true;
  const dx = e.clientX - p.x, dy = e.clientY - p.y;
  if (pointers.size === 2) {
    // Pinch: the change of the distance between the two pointers zooms, their midpoint pans.
    const [a, b] = [...pointers.values()];
    const before = Math.hypot(a.x - b.x, a.y - b.y);
    p.x = e.clientX; p.y = e.clientY;
    const after = Math.hypot(a.x - b.x, a.y - b.y);
    if (before > 0 && after > 0) zoom(before / after);
    pan(dx / 2, dy / 2);
  } else {
    p.x = e.clientX; p.y = e.clientY;
    if (p.button === 2 || p.shift || e.shiftKey) pan(dx, dy);
    else orbit(dx, dy);
  }
  requestView();
});
const release = (e) => {
  const p = pointers.get(e.pointerId);
  if (p && p.grab) sendPointer(e, false, true);
  if (e.type === "pointerup" && p && !p.moved && p.button === 0 && pointers.size === 1) inspect(e);
  pointers.delete(e.pointerId);
  if (pointers.size === 0) canvas.classList.remove("dragging");
};
canvas.addEventListener("pointerup", release);
canvas.addEventListener("pointercancel", release);
canvas.addEventListener("wheel", (e) => {
  if (!S.camera) return;
  e.preventDefault();
  zoom(Math.exp(e.deltaY * 0.001));
  requestView();
}, { passive: false });

$("reset").addEventListener("click", () => {
  if (!S.hello) return;
  S.camera = structuredClone(S.hello.camera);
  requestView();
});

// The frame point under a pointer event, through the canvas's object-fit: contain, in pixels
// of the frame (fractions kept); side by side, both halves show the same pixels.
function framePoint(e) {
  const r = canvas.getBoundingClientRect();
  const s = Math.min(r.width / canvas.width, r.height / canvas.height);
  const ox = (r.width - canvas.width * s) / 2, oy = (r.height - canvas.height * s) / 2;
  const x = (e.clientX - r.left - ox) / s, y = (e.clientY - r.top - oy) / s;
  if (!(x >= 0 && y >= 0 && x < canvas.width && y < canvas.height)) return null;
  const w = S.images.main ? S.images.main.width : canvas.width;
  return [x % w, y];
}

// The frame pixel under a pointer event.
function framePixel(e) {
  const p = framePoint(e);
  return p && [Math.floor(p[0]), Math.floor(p[1])];
}

function inspect(e) {
  const p = framePixel(e);
  if (!p || !S.frame || !S.socket || S.socket.readyState !== WebSocket.OPEN) return;
  S.socket.send(JSON.stringify({ type: "inspect", x: p[0], y: p[1], frame: S.frame.id }));
  const r = canvas.getBoundingClientRect();
  const marker = $("marker");
  marker.style.left = `${e.clientX - r.left}px`;
  marker.style.top = `${e.clientY - r.top}px`;
  marker.hidden = false;
}

function showPixel(m) {
  S.pixel = m;
  const n = m.fragments.length;
  $("pixel-note").textContent =
    `pixel ${m.x}, ${m.y} of frame ${m.frame}, as ${m.method} keeps it: ${n} fragment${n === 1 ? "" : "s"}, front to back`;
  const tbody = $("pixel").tBodies[0];
  tbody.replaceChildren();
  m.fragments.forEach((f, i) => {
    const tr = tbody.insertRow();
    tr.insertCell().textContent = String(i + 1);
    tr.insertCell().textContent = f.depth.toFixed(6);
    const swatch = document.createElement("span");
    swatch.className = "swatch";
    const fill = document.createElement("span");
    fill.style.background = `rgba(${f.rgba[0]}, ${f.rgba[1]}, ${f.rgba[2]}, ${f.rgba[3] / 255})`;
    swatch.append(fill);
    tr.insertCell().append(swatch);
    tr.insertCell().textContent = f.rgba.join(" ");
    const name = f.name ?? `#${f.object}`;
    tr.insertCell().textContent = f.client ? `${name} (${f.client})` : name;
  });
}

// ---- requests ------------------------------------------------------------------------------
let scheduled = false;
// Coalesces the changes of one animation frame into one request.
function requestView() {
  if (scheduled) return;
  scheduled = true;
  requestAnimationFrame(() => {
    scheduled = false;
    sendView();
  });
}

// Whether frames come with a reference image: a compared method, or an audited session.
const comparing = () => (isMfr() ? S.mfr.audit : S.reference !== null);
const sideBySide = () => comparing() && S.show === "side";

// Frames are rendered at the canvas's size in device pixels (sharp on high-density screens),
// at most twice its CSS size: the cost grows with the square.
function frameSize() {
  const h = S.hello;
  const max = h ? (h.mfr || h.remote || h).max_side : 4096;
  if (fixedSize) return fixedSize.map((v) => Math.max(1, Math.min(max, v)));
  const r = canvas.getBoundingClientRect();
  const dpr = Math.max(1, Math.min(2, window.devicePixelRatio || 1));
  const width = (sideBySide() ? r.width / 2 : r.width) * dpr;
  return [Math.max(1, Math.min(max, Math.round(width))), Math.max(1, Math.min(max, Math.round(r.height * dpr)))];
}

function sendView() {
  if (!S.socket || S.socket.readyState !== WebSocket.OPEN || !S.camera) return;
  $("marker").hidden = true; // the inspected pixel belongs to the previous view
  const [width, height] = frameSize();
  const id = S.nextId++;
  S.sent.set(id, performance.now());
  if (S.sent.size > 256) S.sent.delete(S.sent.keys().next().value);
  S.lastSentId = id;
  if (isMfr()) {
    S.socket.send(JSON.stringify({ type: "mfr", id, width, height, camera: S.camera, ...S.mfr }));
    return;
  }
  if (isRemote()) {
    S.socket.send(JSON.stringify({ type: "remote", id, width, height, camera: S.camera, ...S.remote }));
    return;
  }
  const request = {
    type: "view", id, width, height, frame: S.animationFrame,
    camera: S.camera, method: S.method, options: S.options,
  };
  if (S.reference !== null) {
    request.compare = { method: S.reference, options: S.referenceOptions, flip: S.show === "flip" };
  }
  S.socket.send(JSON.stringify(request));
}

new ResizeObserver(() => { if (!fixedSize) requestView(); }).observe(canvas);

// ---- multi-frame-rate settings -------------------------------------------------------------
function buildMfr() {
  $("mfr-section").hidden = false;
  $("method-section").hidden = true;
  $("compare-section").hidden = true;
  $("histogram-box").hidden = true;
  $("mfr-section").append($("split-row"));
  const hz = $("fc-hz"), interval = $("sc-interval");
  hz.max = String(S.hello.mfr.max_fc_hz);
  interval.max = String(S.hello.mfr.max_sc_interval_ms);
  const number = (input, lo, hi, fallback) => {
    const v = Number(input.value);
    const clamped = Number.isFinite(v) ? Math.max(lo, Math.min(hi, v)) : fallback;
    input.value = String(clamped);
    return clamped;
  };
  $("composition").onchange = () => { S.mfr.composition = $("composition").value; requestView(); };
  $("migration").onchange = () => { S.mfr.migration = $("migration").value; requestView(); };
  hz.onchange = () => { S.mfr.fc_hz = number(hz, 1, Number(hz.max), 30); requestView(); };
  interval.onchange = () => {
    S.mfr.sc_interval_ms = number(interval, 0, Number(interval.max), 0);
    requestView();
  };
  $("audit").onchange = () => {
    S.mfr.audit = $("audit").checked;
    $("mfr-show-row").hidden = !S.mfr.audit;
    $("split-row").hidden = !(S.mfr.audit && S.show === "split");
    requestView();
  };
  $("mfr-show").onchange = () => {
    S.show = $("mfr-show").value;
    $("split-row").hidden = S.show !== "split";
    draw(); // the images are there; a new size (side by side or not) follows with the frame
    requestView();
  };
  $("split").oninput = () => {
    S.split = $("split").value / 100;
    draw();
  };
}

// ---- remote settings -----------------------------------------------------------------------
function buildRemote() {
  const r = S.hello.remote;
  $("remote-section").hidden = false;
  $("method-section").hidden = true;
  $("compare-section").hidden = true;
  $("histogram-box").hidden = true;
  $("remote-note").textContent =
    `${r.nodes.length} node${r.nodes.length === 1 ? "" : "s"} · ${r.transfer} · ${r.codec} · ` +
    `${r.in_flight} frame${r.in_flight === 1 ? "" : "s"} in flight · a node silent for ` +
    `${r.timeout_s} s is ${r.on_fault === "hold" ? "held" : "dropped"}`;
  // A transfer chosen here restarts the display with it (the nodes start over from a full frame).
  const transfer = $("transfer"), layers = $("layers");
  transfer.options[0].textContent = `as started (${r.transfer})`;
  const setTransfer = () => {
    delete S.remote.transfer;
    delete S.remote.layers;
    const name = transfer.value;
    $("layers-row").hidden = name !== "depth-limited";
    if (name) S.remote.transfer = name;
    if (name === "depth-limited") {
      const v = Math.round(Number(layers.value));
      S.remote.layers = Number.isFinite(v) ? Math.max(1, Math.min(1024, v)) : 6;
      layers.value = String(S.remote.layers);
    }
    requestView();
  };
  transfer.onchange = setTransfer;
  layers.onchange = setTransfer;
  const fps = $("max-fps");
  fps.max = String(r.max_fps);
  fps.onchange = () => {
    const v = Number(fps.value);
    S.remote.max_fps = Number.isFinite(v) ? Math.max(1, Math.min(r.max_fps, v)) : 30;
    fps.value = String(S.remote.max_fps);
    requestView();
  };
}

// The display's numbers: every node's row, the incidents, the frame's totals.
function showRemoteStats(h) {
  const r = h.remote;
  const nodes = $("nodes").tBodies[0];
  nodes.replaceChildren();
  for (const n of r.nodes) {
    const tr = nodes.insertRow();
    tr.dataset.status = n.status;
    tr.insertCell().textContent = n.node;
    tr.cells[0].title = n.node;
    const status = tr.insertCell();
    status.textContent = n.status;
    status.className = n.status;
    tr.insertCell().textContent = fmt(Math.round(n.bytes / 1024));
    const sent = tr.insertCell();
    sent.textContent = fmt(n.fragments_sent);
    sent.title = `${fmt(n.fragments_sent)} of ${fmt(n.fragments_rendered)} fragments rendered`;
    const ms = (v) => Math.round(v).toString();
    tr.insertCell().textContent =
      `${ms(n.render_ms + n.select_ms + n.encode_ms)} / ${ms(n.transfer_ms)} / ${ms(n.decode_ms)}`;
  }
  $("incident-count").textContent = r.incident_count ? `(${fmt(r.incident_count)})` : "(none)";
  $("incidents").replaceChildren(...r.incidents.map((i) => {
    const li = document.createElement("li");
    li.textContent = `frame ${i.frame}: ${i.node}: ${i.what}`;
    return li;
  }));
  const tbody = $("stats").tBodies[0];
  tbody.replaceChildren();
  row(tbody, "frame", fmt(r.frame));
  row(tbody, "display frames a second", fmt(r.fps));
  row(tbody, "transfer", r.transfer);
  row(tbody, "codec", r.codec);
  row(tbody, "fragments displayed", fmt(r.fragments_displayed));
  row(tbody, "received KiB", fmt(r.bytes / 1024));
  row(tbody, "as raw lists KiB", fmt(r.raw_bytes / 1024), "pass");
  row(tbody, "apply ms", fmt(r.merge_ms));
  row(tbody, "merge + resolve ms", fmt(r.resolve_ms));
  row(tbody, "since the last frame ms", fmt(r.interval_ms));
  if (S.latencyMs !== null) row(tbody, "camera → frame ms", fmt(Math.round(S.latencyMs)));
  row(tbody, "PNG encode ms", fmt(h.encode_ms));
  row(tbody, "PNG KiB", fmt(h.png_bytes / 1024));
  $("camera").value = h.camera_toml;
}

// ---- method and options --------------------------------------------------------------------
function buildMethods() {
  const select = $("method");
  select.replaceChildren(...S.hello.methods.map((m) => new Option(m.name, m.name)));
  select.value = S.method;
  select.onchange = () => {
    S.method = select.value;
    S.options = {};
    buildOptions();
    requestView();
  };
  const reference = $("reference");
  reference.append(...S.hello.methods.map((m) => new Option(m.name, m.name)));
  reference.onchange = () => {
    S.reference = reference.value || null;
    S.referenceOptions = {};
    buildOptions();
    requestView();
  };
  $("show").onchange = () => {
    S.show = $("show").value;
    $("split-row").hidden = S.show !== "split";
    requestView();
  };
  $("split").oninput = () => {
    S.split = $("split").value / 100;
    draw();
  };
  buildOptions();
}

function buildOptions() {
  const info = S.hello.methods.find((m) => m.name === S.method);
  $("method-summary").textContent = info ? `${info.summary} (${info.fidelity})` : "";
  optionForm($("options"), S.method, () => S.options, (o) => { S.options = o; }, () => S.method);
  optionForm($("reference-options"), S.reference, () => S.referenceOptions,
    (o) => { S.referenceOptions = o; }, () => S.reference);
}

// The form of `method`'s options in `box`: exactly the options it reads, with the command
// line's help and defaults. `current` gives the live setting, which this form belongs to.
function optionForm(box, method, get, set, current) {
  box.replaceChildren();
  const info = S.hello.methods.find((m) => m.name === method);
  if (!info) return;
  for (const name of info.options) {
    const spec = S.hello.options.find((o) => o.name === name);
    if (!spec) continue; // --weights: a file on the server, not offered here
    const row = document.createElement("div");
    row.className = "option";
    const label = document.createElement("label");
    label.append(name);
    const input = document.createElement("input");
    input.name = name;
    input.dataset.option = name;
    const options = get();
    if (spec.flag) {
      input.type = "checkbox";
      input.checked = (options[name] ?? spec.default) === "true";
    } else {
      input.type = "text";
      input.value = options[name] ?? spec.default ?? "";
      input.placeholder = spec.default ?? "";
    }
    input.title = spec.help;
    input.onchange = () => {
      // A field edited and left by switching the method fires after the switch: it is gone.
      if (current() !== method || !input.isConnected) return;
      const value = spec.flag ? String(input.checked) : input.value.trim();
      const next = { ...get() };
      if (value === (spec.default ?? "")) delete next[name];
      else next[name] = value;
      set(next);
      input.classList.toggle("changed", name in next);
      requestView();
    };
    input.classList.toggle("changed", name in options);
    label.append(input);
    const help = document.createElement("p");
    help.className = "note";
    help.textContent = spec.help;
    row.append(label, help);
    box.append(row);
  }
}

// ---- frames --------------------------------------------------------------------------------
// Newest wins here too: while a frame decodes, only the newest frame that arrived meanwhile
// waits; older ones are dropped undecoded. Deep EXRs are never dropped.
let waiting = null;
let decoding = false;

function receive(buffer) {
  const n = new DataView(buffer).getUint32(0, true);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, n)));
  if (header.type === "deep") {
    saveDeep(header, buffer, 4 + n);
    return;
  }
  waiting = { header, buffer, first: 4 + n };
  if (!decoding) decodeNext();
}

async function decodeNext() {
  decoding = true;
  while (waiting) {
    const { header, buffer, first } = waiting;
    waiting = null;
    try {
      await showFrame(header, buffer, first);
    } catch (err) {
      showError(null, `cannot show the frame: ${err}`);
    }
  }
  decoding = false;
}

function saveDeep(header, buffer, first) {
  const bytes = new Uint8Array(buffer, first, header.images[0].bytes);
  S.savedDeep = { frame: header.frame, bytes: bytes.length };
  download(new Blob([bytes], { type: "image/x-exr" }), `${S.hello.scene}-${S.method}-deep.exr`);
}

function download(blob, name) {
  const a = document.createElement("a");
  a.href = URL.createObjectURL(blob);
  a.download = name;
  a.click();
  setTimeout(() => URL.revokeObjectURL(a.href), 1000);
}

// The frame's PNGs, all decoded at once; an image sent in bands (consecutive entries of one
// name, each a PNG of `rows` full-width rows) is stacked top to bottom into one bitmap.
async function decodeImages(header, buffer, first) {
  let at = first;
  const parts = header.images.map(({ name, bytes }) => {
    const png = new Blob([new Uint8Array(buffer, at, bytes)], { type: "image/png" });
    at += bytes;
    return { name, bitmap: createImageBitmap(png, { colorSpaceConversion: "none", premultiplyAlpha: "none" }) };
  });
  const bitmaps = await Promise.all(parts.map((p) => p.bitmap));
  const images = {};
  for (let i = 0; i < parts.length;) {
    let end = i + 1;
    while (end < parts.length && parts[end].name === parts[i].name) end++;
    images[parts[i].name] = end - i === 1 ? bitmaps[i] : stackBands(bitmaps.slice(i, end));
    i = end;
  }
  return images;
}

function stackBands(bands) {
  const height = bands.reduce((sum, b) => sum + b.height, 0);
  const canvas = new OffscreenCanvas(bands[0].width, height);
  const ctx = canvas.getContext("2d");
  let y = 0;
  for (const band of bands) {
    ctx.drawImage(band, 0, y);
    y += band.height;
    band.close();
  }
  return canvas.transferToImageBitmap();
}

async function showFrame(header, buffer, first) {
  const images = await decodeImages(header, buffer, first);
  if (S.frame && header.id < S.frame.id) return; // an older frame decoded late
  for (const old of Object.values(S.images)) old.close();
  S.images = images;
  S.frame = header;
  draw();
  S.framesShown++;
  const now = performance.now();
  const sent = S.sent.get(header.id);
  if (sent !== undefined) {
    S.latencyMs = now - sent;
    S.sent.delete(header.id); // later frames of the same settings (MFR) are not its answer
  }
  const seq = header.mfr && header.mfr.pointer_seq;
  if (seq && seq !== S.pointerShown) {
    S.pointerShown = seq;
    const at = S.pointerSent.get(seq);
    if (at !== undefined) S.pointerLatencyMs = now - at;
  }
  S.shownTimes.push(now);
  while (S.shownTimes.length && S.shownTimes[0] < now - 1000) S.shownTimes.shift();
  // A frame answers every request before it: their errors are settled.
  if (S.errors.length && S.errors[S.errors.length - 1].id !== null
      && S.errors[S.errors.length - 1].id <= header.id) {
    $("error").hidden = true;
  }
  // Over an object the session can grab, the cursor says so.
  canvas.classList.toggle("over", Boolean(header.mfr && header.mfr.over));
  showStats(header);
  showStatus();
  window.dispatchEvent(new CustomEvent("strata-frame", { detail: header }));
}

// Draws the frame's images as `show` asks (the method's image alone without a reference).
function draw() {
  const { main, reference, bad, flip } = S.images;
  if (!main) return;
  const w = main.width, h = main.height;
  const show = reference && comparing() ? S.show : "main";
  // Setting a canvas's size, even to the same value, gives it a fresh backing store: only when
  // it changes (each frame covers the whole canvas anyway).
  const width = show === "side" ? 2 * w : w;
  if (canvas.width !== width || canvas.height !== h) {
    canvas.width = width;
    canvas.height = h;
  }
  if (show === "side") {
    ctx.drawImage(main, 0, 0);
    ctx.drawImage(reference, w, 0);
  } else if (show === "split") {
    const at = Math.round(S.split * w);
    ctx.drawImage(reference, 0, 0);
    ctx.drawImage(main, 0, 0, at, h, 0, 0, at, h);
    ctx.fillStyle = "#fff";
    ctx.fillRect(Math.min(at, w - 1), 0, 1, h);
  } else {
    const image = { bad, flip, reference, main }[show] ?? main;
    ctx.drawImage(image, 0, 0);
  }
}

function row(tbody, label, value, cls) {
  const tr = tbody.insertRow();
  if (cls) tr.className = cls;
  tr.insertCell().textContent = label;
  tr.insertCell().textContent = value;
}

const fmt = (n) => (typeof n === "number" ? n.toLocaleString("en-US", { maximumFractionDigits: 2 }) : String(n));
const mib = (b) => `${(b / 1048576).toFixed(1)} MiB`;

// The multi-frame-rate session's numbers.
function showMfrStats(h) {
  const m = h.mfr;
  const tbody = $("stats").tBodies[0];
  tbody.replaceChildren();
  const names = (list) => (list.length ? list.join(", ") : "none");
  row(tbody, "composition", m.composition);
  row(tbody, "migration", m.migration);
  row(tbody, "FC frames a second", fmt(m.fc_fps));
  row(tbody, "FC frame ms", fmt(m.fc_ms));
  row(tbody, "SC frames a second", fmt(m.sc_fps));
  row(tbody, "SC frame ms", fmt(m.sc_ms));
  row(tbody, "SC buffer age ms", m.sc_age_ms === null ? "(no SC buffer yet)" : fmt(m.sc_age_ms));
  row(tbody, "SC frames", fmt(m.sc_frames));
  row(tbody, "state snapshot", fmt(m.snapshot));
  row(tbody, "FC draws", names(m.fc_objects));
  row(tbody, "under the pointer", m.over ?? "nothing");
  row(tbody, "selected", m.selected ?? "nothing");
  for (const o of m.moved) row(tbody, `${o.name} moved by`, o.offset.map((v) => v.toFixed(3)).join(", "), "pass");
  if (S.pointerLatencyMs !== null) row(tbody, "pointer → frame ms", fmt(Math.round(S.pointerLatencyMs)));
  for (const what of m.incidents || []) row(tbody, "incident", what, "bad");
  const a = m.audit;
  if (a) {
    row(tbody, "bad pixels (audit)", fmt(a.bad_pixels));
    row(tbody, "ghost / hole / blend", `${fmt(a.ghost_pixels)} / ${fmt(a.hole_pixels)} / ${fmt(a.blend_pixels)}`);
    row(tbody, "RMSE", a.rmse.toFixed(4));
    row(tbody, "audit ms", fmt(a.ms));
  }
  row(tbody, "PNG encode ms", fmt(h.encode_ms));
  row(tbody, "PNG KiB", fmt(h.png_bytes / 1024));
  $("camera").value = h.camera_toml;
}

function showStats(h) {
  if (h.mfr) {
    showMfrStats(h);
    return;
  }
  if (h.remote) {
    showRemoteStats(h);
    return;
  }
  const s = h.stats;
  const tbody = $("stats").tBodies[0];
  tbody.replaceChildren();
  row(tbody, "method", s.method);
  row(tbody, "size", `${s.width} × ${s.height}`);
  row(tbody, "fragments kept", fmt(s.fragments));
  row(tbody, "fragments rasterised", fmt(s.fragments_rasterized));
  row(tbody, "lost (dropped)", fmt(s.dropped_fragments));
  row(tbody, "covered pixels", fmt(s.covered_pixels));
  row(tbody, "depth max / mean", `${fmt(s.max_depth_complexity)} / ${fmt(s.mean_depth_complexity)}`);
  row(tbody, "memory used / allocated", `${mib(s.used_memory_bytes)} / ${mib(s.memory_bytes)}`);
  row(tbody, "render ms", fmt(h.render_ms));
  for (const [pass, ms] of Object.entries(s.timings_ms)) row(tbody, pass, fmt(ms), "pass");
  row(tbody, "PNG encode ms", fmt(h.encode_ms));
  row(tbody, "PNG KiB", fmt(h.png_bytes / 1024));
  const c = h.compare;
  if (c) {
    row(tbody, "reference", c.method);
    row(tbody, "reference render ms", fmt(c.render_ms));
    row(tbody, "RMSE", c.rmse.toFixed(4));
    row(tbody, `bad pixels (> ${c.bad_pixels.threshold} steps)`,
      `${fmt(c.bad_pixels.count)} (${(100 * c.bad_pixels.share).toFixed(2)} %)`);
    row(tbody, "mean FLIP", c.mean_flip === null ? "(shown with its heat map)" : c.mean_flip.toFixed(4));
  }
  $("camera").value = h.camera_toml;
  const hist = s.depth_histogram || [];
  const max = Math.max(1, ...hist.slice(1));
  $("histogram").replaceChildren(...hist.slice(1).map((count, i) => {
    const bar = document.createElement("div");
    bar.style.height = `${(100 * count) / max}%`;
    bar.title = `${i + 1} fragment(s): ${count} pixels`;
    return bar;
  }));
}

function showStatus() {
  const el = $("status");
  const up = S.socket && S.socket.readyState === WebSocket.OPEN;
  el.classList.toggle("down", !up);
  if (!up) {
    el.textContent = "disconnected: reconnecting…";
    return;
  }
  const parts = [`${S.shownTimes.length} fps`];
  const m = S.frame && S.frame.mfr;
  const r = S.frame && S.frame.remote;
  if (r) {
    const ok = r.nodes.filter((n) => n.status === "ok").length;
    parts.push(`frame ${r.frame}`, `${ok} of ${r.nodes.length} nodes ok`);
    if (S.latencyMs !== null) parts.push(`latency ${Math.round(S.latencyMs)} ms`);
  } else if (m) {
    parts.push(`SC ${fmt(m.sc_fps)} fps`);
    if (m.sc_age_ms !== null) parts.push(`SC age ${Math.round(m.sc_age_ms)} ms`);
    parts.push(m.composition);
    if (m.audit) parts.push(`${fmt(m.audit.bad_pixels)} bad pixels`);
  } else {
    if (S.frame) parts.push(`render ${fmt(S.frame.render_ms)} ms`);
    if (S.latencyMs !== null) parts.push(`latency ${Math.round(S.latencyMs)} ms`);
  }
  el.textContent = parts.join(" · ");
}

function showError(id, message) {
  S.errors.push({ id, message });
  if (S.errors.length > 100) S.errors.shift();
  const el = $("error");
  el.textContent = message;
  el.hidden = false;
}

// ---- connection ----------------------------------------------------------------------------
let retryMs = 250;

function connect() {
  const socket = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
  socket.binaryType = "arraybuffer";
  S.socket = socket;
  socket.onopen = () => {
    S.connects++;
    retryMs = 250;
    showStatus();
  };
  socket.onmessage = (e) => {
    if (typeof e.data !== "string") {
      receive(e.data);
      return;
    }
    const m = JSON.parse(e.data);
    if (m.type === "hello") {
      $("error").hidden = true; // whatever kept the page out (too many pages) is over
      const first = S.hello === null;
      // A server restarted with another scene, mode or method list: start the page afresh.
      const offer = (h) => JSON.stringify([h.scene, h.origin, h.mfr, h.remote, h.methods, h.options]);
      if (!first && offer(m) !== offer(S.hello)) {
        location.reload();
        return;
      }
      S.hello = m;
      if (first) {
        S.camera = structuredClone(m.camera);
        S.method = m.method;
        S.options = { ...m.method_options };
        $("scene").textContent = `${m.scene}: ${fmt(m.triangles)} triangles (${m.origin})`;
        document.title = `strata view: ${m.scene}`;
        buildMethods();
        if (m.mfr) buildMfr();
        if (m.remote) buildRemote();
        if (m.frames > 1 && !m.mfr && !m.remote) {
          const input = $("animation");
          input.max = String(m.frames - 1);
          $("animation-row").hidden = false;
          input.onchange = () => {
            S.animationFrame = Math.max(0, Math.min(m.frames - 1, Math.round(Number(input.value) || 0)));
            input.value = String(S.animationFrame);
            requestView();
          };
        }
      }
      sendView(); // the view as it is, also after a reconnection
    } else if (m.type === "pixel") {
      showPixel(m);
    } else if (m.type === "error") {
      showError(m.id, m.message);
    }
  };
  socket.onclose = () => {
    if (S.socket !== socket) return;
    showStatus();
    setTimeout(connect, retryMs);
    retryMs = Math.min(2000, retryMs * 2);
  };
}

$("copy").addEventListener("click", () => {
  const text = $("camera").value;
  if (navigator.clipboard) navigator.clipboard.writeText(text).catch(() => {});
  $("camera").select();
});

$("screenshot").addEventListener("click", () => {
  canvas.toBlob((blob) => {
    if (blob) download(blob, `${S.hello ? S.hello.scene : "strata"}-${S.method}.png`);
  }, "image/png");
});

$("save-deep").addEventListener("click", () => {
  if (S.socket && S.socket.readyState === WebSocket.OPEN) S.socket.send(JSON.stringify({ type: "save_deep" }));
});

setInterval(showStatus, 500);
connect();
