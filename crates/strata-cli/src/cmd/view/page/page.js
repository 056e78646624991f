// strata view: the page. Plain JavaScript, no build step; served by `strata view`.
//
// The page owns the view (camera, size, method and options) and sends it whole on every change;
// the server renders the newest view it has and sends back a frame: a u32 little-endian header
// length, a JSON header (request id, `strata render --stats` statistics, the camera as scene-file
// lines) and a PNG. See crates/strata-cli/src/cmd/view/protocol.rs.
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

const pointers = new Map(); // pointerId -> {x, y}
canvas.addEventListener("contextmenu", (e) => e.preventDefault());
canvas.addEventListener("pointerdown", (e) => {
  if (!S.camera) return;
  canvas.setPointerCapture(e.pointerId);
  pointers.set(e.pointerId, {
    x: e.clientX, y: e.clientY, x0: e.clientX, y0: e.clientY, moved: false,
    button: e.button, shift: e.shiftKey,
  });
  canvas.classList.add("dragging");
});
canvas.addEventListener("pointermove", (e) => {
  const p = pointers.get(e.pointerId);
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

// The frame pixel under a pointer event, through the canvas's object-fit: contain.
function framePixel(e) {
  const r = canvas.getBoundingClientRect();
  const s = Math.min(r.width / canvas.width, r.height / canvas.height);
  const ox = (r.width - canvas.width * s) / 2, oy = (r.height - canvas.height * s) / 2;
  const x = Math.floor((e.clientX - r.left - ox) / s), y = Math.floor((e.clientY - r.top - oy) / s);
  if (!(x >= 0 && y >= 0 && x < canvas.width && y < canvas.height)) return null;
  // Side by side, both halves show the same pixels: the method's store is inspected.
  const w = S.frame ? S.frame.stats.width : canvas.width;
  return [x % w, y];
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
    tr.insertCell().textContent = f.name ?? `#${f.object}`;
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

const sideBySide = () => S.reference !== null && S.show === "side";

function frameSize() {
  const max = S.hello ? S.hello.max_side : 4096;
  if (fixedSize) return fixedSize.map((v) => Math.max(1, Math.min(max, v)));
  const r = canvas.getBoundingClientRect();
  const width = sideBySide() ? r.width / 2 : r.width;
  return [Math.max(1, Math.min(max, Math.round(width))), Math.max(1, Math.min(max, Math.round(r.height)))];
}

function sendView() {
  if (!S.socket || S.socket.readyState !== WebSocket.OPEN || !S.camera) return;
  $("marker").hidden = true; // the inspected pixel belongs to the previous view
  const [width, height] = frameSize();
  const id = S.nextId++;
  S.sent.set(id, performance.now());
  if (S.sent.size > 256) S.sent.delete(S.sent.keys().next().value);
  S.lastSentId = id;
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

async function showFrame(header, buffer, first) {
  const images = {};
  let at = first;
  for (const { name, bytes } of header.images) {
    const png = new Blob([new Uint8Array(buffer, at, bytes)], { type: "image/png" });
    images[name] = await createImageBitmap(png, { colorSpaceConversion: "none", premultiplyAlpha: "none" });
    at += bytes;
  }
  if (S.frame && header.id < S.frame.id) return; // an older frame decoded late
  for (const old of Object.values(S.images)) old.close();
  S.images = images;
  S.frame = header;
  draw();
  S.framesShown++;
  const now = performance.now();
  const sent = S.sent.get(header.id);
  if (sent !== undefined) S.latencyMs = now - sent;
  S.shownTimes.push(now);
  while (S.shownTimes.length && S.shownTimes[0] < now - 1000) S.shownTimes.shift();
  // A frame answers every request before it: their errors are settled.
  if (S.errors.length && S.errors[S.errors.length - 1].id !== null
      && S.errors[S.errors.length - 1].id <= header.id) {
    $("error").hidden = true;
  }
  showStats(header);
  showStatus();
  window.dispatchEvent(new CustomEvent("strata-frame", { detail: header }));
}

// Draws the frame's images as `show` asks (the method's image alone without a reference).
function draw() {
  const { main, reference, bad, flip } = S.images;
  if (!main) return;
  const w = main.width, h = main.height;
  const show = reference ? S.show : "main";
  canvas.width = show === "side" ? 2 * w : w;
  canvas.height = h;
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

function showStats(h) {
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
  if (S.frame) parts.push(`render ${fmt(S.frame.render_ms)} ms`);
  if (S.latencyMs !== null) parts.push(`latency ${Math.round(S.latencyMs)} ms`);
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
      S.hello = m;
      if (first) {
        S.camera = structuredClone(m.camera);
        S.method = m.method;
        S.options = { ...m.method_options };
        $("scene").textContent = `${m.scene}: ${fmt(m.triangles)} triangles (${m.origin})`;
        document.title = `strata view: ${m.scene}`;
        buildMethods();
        if (m.frames > 1) {
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
