// puppet live view: frames from the server's renderer on one socket, panel and input on another.
// Frame message: 24-byte little-endian header (type u8, flags u8, camera u16, seq u32,
// reading time i64 ns, send time i64 ns) then a JPEG. Each frame is acknowledged once drawn.
"use strict";

const HEADER = 24;
const FLAG_DRAFT = 1;
const HANDLE_RADIUS = 7;
const PIN_DRAG_PX = 4;     // a press pins a point only once the pointer moved this far (screen px): a click pins nothing
const MAX_NOTICES = 50;    // notices kept (state.notices and the list): the newest
const MAX_FAULTS = 200;    // bus events kept

const query = new URLSearchParams(location.search);
const token = query.get("token");
const client = Array.from(crypto.getRandomValues(new Uint8Array(12)), b => b.toString(16).padStart(2, "0")).join("");

// Everything the page knows, readable from the console and by tests.
const state = {
  client, viewer: null, mode: null, width: 640, height: 480,
  shownSeq: -1, shown: 0, draft: false, drafts: 0, fps: 0, shownTimes: [],
  servos: [], handles: [], handleSpots: [], bones: [], overlay: true, ownCamera: false,
  recording: { on: false }, faults: [], markers: [], notices: [], panel: null, playback: null, takeMarks: [],
  connected: { frames: false, control: false }, lastPick: null,
  keys: null, keysUpdates: 0, selectedKey: null,  // selectedKey: the key (index) the key buttons edit  // the shot's keys (puppet keys --view) and how many updates came
  panels: 0, panelTimes: [],  // panel updates received; arrival times (ms, performance.now), newest 600
};
window.puppetView = state;

const frameCanvas = document.getElementById("frame");
const frameCtx = frameCanvas.getContext("2d", { alpha: false });  // opaque: no blending when composited
const marks = document.getElementById("marks");
const marksCtx = marks.getContext("2d");
const $ = id => document.getElementById(id);

function socketUrl(path) {
  const url = new URL(path, location.href);
  url.protocol = location.protocol === "https:" ? "wss:" : "ws:";
  url.search = "";
  url.searchParams.set("client", client);
  if (token) url.searchParams.set("token", token);
  return url.toString();
}

// ---- frames -------------------------------------------------------------------------------
let frames = null;
let drawing = Promise.resolve();

function connectFrames() {
  frames = new WebSocket(socketUrl("ws/frames"));
  frames.binaryType = "arraybuffer";
  frames.onopen = () => { state.connected.frames = true; showConnection(); };
  frames.onclose = () => { state.connected.frames = false; showConnection(); setTimeout(connectFrames, 1000); };
  frames.onmessage = event => {
    const data = event.data;
    const arrived = performance.now();
    if (!(data instanceof ArrayBuffer) || data.byteLength <= HEADER) return;
    const head = new DataView(data, 0, HEADER);
    const flags = head.getUint8(1);
    const seq = head.getUint32(4, true);
    const blob = new Blob([new Uint8Array(data, HEADER)], { type: "image/jpeg" });
    const socket = frames;
    // Decode in parallel, draw in order; acknowledge after drawing (the server's credit).
    const decoded = createImageBitmap(blob);
    drawing = drawing.then(() => decoded).then(bitmap => {
      if (bitmap.width !== frameCanvas.width || bitmap.height !== frameCanvas.height) {
        frameCanvas.width = marks.width = bitmap.width;
        frameCanvas.height = marks.height = bitmap.height;
        state.width = bitmap.width; state.height = bitmap.height;
        document.documentElement.style.setProperty("--frame-w", `${bitmap.width}px`);
        $("stage").style.aspectRatio = `${bitmap.width} / ${bitmap.height}`;
      }
      frameCtx.drawImage(bitmap, 0, 0);
      bitmap.close();
      state.shownSeq = seq;
      state.draft = (flags & FLAG_DRAFT) !== 0;
      if (state.draft) state.drafts += 1;
      state.shown += 1;
      const now = performance.now();
      state.shownTimes.push(now);
      while (state.shownTimes.length && now - state.shownTimes[0] > 2000) state.shownTimes.shift();
    }, () => {}).finally(() => {
      // drawn_ms: arrival -> drawn on this page's clock (the server splits its latency with it).
      const drawnMs = Math.round((performance.now() - arrived) * 100) / 100;
      if (socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify({ type: "ack", seq, drawn_ms: drawnMs }));
    });
  };
}

// ---- control ------------------------------------------------------------------------------
let control = null;
const pending = [];

function send(message) {
  if (control && control.readyState === WebSocket.OPEN) control.send(JSON.stringify(message));
  else pending.push(message);
}

function connectControl() {
  control = new WebSocket(socketUrl("ws/control"));
  control.onopen = () => {
    state.connected.control = true; showConnection();
    while (pending.length) control.send(JSON.stringify(pending.shift()));
    if (state.ownCamera) send({ type: "camera_mode", own: true });
  };
  control.onclose = () => { state.connected.control = false; showConnection(); setTimeout(connectControl, 1000); };
  control.onmessage = event => {
    let message;
    try { message = JSON.parse(event.data); } catch (e) { return; }
    const handler = handlers[message.type];
    if (handler) handler(message);
  };
}

const handlers = {
  snapshot(m) {
    state.viewer = m.viewer; state.mode = m.mode; state.servos = m.servos; state.handles = m.handles;
    state.faults = m.faults.slice(); state.markers = m.markers.slice(); state.overlay = m.overlay;
    buildServoTable(m.servos);
    $("faults").replaceChildren(); $("events").replaceChildren(); m.faults.forEach(addFault);
    showLegend(m.legend || []);
    setOverlay(m.overlay); setRecording(m.recording, true);
    $("playback").hidden = m.mode !== "play";
    $("record").disabled = m.mode !== "live";  // a take of the rest pose or of a take: nothing new
    if (m.panel && m.panel.servos) handlers.panel(m.panel);
    $("keys").hidden = !m.keys;
    if (m.keys && m.ghost_legend) {  // the onion skins' colours, beside the bone legend
      $("onion-legend").replaceChildren(...m.ghost_legend.filter(g => g.what.endsWith("key")).map(g => {
        const li = document.createElement("li"), swatch = document.createElement("span");
        swatch.className = "swatch"; swatch.style.background = g.color;
        li.append(swatch, document.createTextNode(g.what)); return li;
      }));
      $("onion-legend").hidden = false;
    }
    if (m.keys) handlers.keys(m.keys);
  },
  keys(m) {
    state.keys = m; state.keysUpdates += 1;
    $("onion").setAttribute("aria-pressed", String(m.onion));
    const last = m.keys.length ? m.keys[m.keys.length - 1].frame : 0;
    $("keys-count").textContent = `${m.keys.length} keys · ${last} frames at ${m.fps} fps · next key at frame ${m.next_frame}`;
    const said = $("keys-said");
    said.textContent = m.said || "";
    said.classList.toggle("refused", m.taken === false);
    if (state.selectedKey !== null && state.selectedKey >= m.keys.length) state.selectedKey = null;
    showSelectedKey();
  },
  panel(m) {
    state.panel = m;
    state.panels += 1;
    state.panelTimes.push(performance.now());
    if (state.panelTimes.length > 600) state.panelTimes.shift();
    if (m.servos) updateServos(m.servos);
    if (m.handles) state.handleSpots = m.handles;
    if (m.bones) state.bones = m.bones;
    if (m.viewer) { $("drops").textContent = m.viewer.drops + (m.drops ? ` (+${m.drops} skipped)` : ""); }
    $("loop-fps").textContent = m.loop_fps !== undefined ? m.loop_fps.toFixed(0) : "–";
    // This tab's own reading -> drawn latency (each tab has its own figure).
    const own = m.viewer && m.viewer.latency_ms;
    if (own && own.median !== null) $("latency").textContent = `${own.median} (p99 ${own.p99})`;
    if (m.recording) setRecording(m.recording);
    if (m.playback) updatePlayback(m.playback);
    drawMarks();
  },
  fault(m) { state.faults.push(m); if (state.faults.length > MAX_FAULTS) state.faults.shift(); addFault(m); },
  handles(m) { state.handles = m.handles; },
  handle(m) {
    state.lastPick = { key: m.key, handle: m.handle, refactor_ms: m.refactor_ms };
    if (drag && drag.key === m.key) { drag.handle = m.handle; drag.pending = false; }
    if (m.refactor_ms !== undefined) note(`handle ${m.handle}: refactor ${m.refactor_ms} ms`);
  },
  pick_miss(m) {
    state.lastPick = { key: m.key, handle: null };
    if (drag && drag.key === m.key) {  // the background: the drag orbits instead
      drag.pending = false; drag.orbit = true;
      queueMove("orbit", drag.x - drag.startX, drag.y - drag.startY);
    }
  },
  overlay(m) { setOverlay(m.on); },
  recording(m) { setRecording(m); },
  marker(m) { state.markers.push(m); note(`marker "${m.name}" at ${m.t_s} s`); },
  notice(m) { note(m.text); },
};

function showConnection() {
  const ok = state.connected.frames && state.connected.control;
  const el = $("connection");
  el.textContent = ok ? `viewer ${state.viewer ?? ""}` : "disconnected";
  el.className = ok ? "ok" : "bad";
}

function note(text) {
  state.notices.push({ text, t: performance.now() });
  if (state.notices.length > MAX_NOTICES) state.notices.shift();
  const li = document.createElement("li");
  li.textContent = text;
  $("notices").prepend(li);
  while ($("notices").children.length > MAX_NOTICES) $("notices").lastChild.remove();
}

// ---- panel --------------------------------------------------------------------------------
function buildServoTable(servos) {
  const body = $("servos").tBodies[0];
  body.replaceChildren();
  for (const s of servos) {
    const row = body.insertRow();
    row.dataset.id = s.id;
    row.insertCell().textContent = s.id;
    const joint = row.insertCell(); joint.textContent = s.joint; joint.title = s.joint;
    const angle = row.insertCell(); angle.className = "num"; angle.textContent = "–";
    row.insertCell().textContent = "–";
    row.insertCell().textContent = "";
  }
}

// Only what changed is written: every write restyles and repaints the table.
function setText(cell, text) { if (cell.textContent !== text) cell.textContent = text; }

function updateServos(servos) {
  const body = $("servos").tBodies[0];
  servos.forEach((s, i) => {
    const row = body.rows[i];
    if (!row) return;
    setText(row.cells[2], s.deg.toFixed(1));
    setText(row.cells[3], s.state);  // ok, late (held, not a fault) or fault (panel.SERVO_STATES)
    const state = "state-" + s.state;
    if (row.cells[3].className !== state) row.cells[3].className = state;
    setText(row.cells[4], s.fault);
    if (row.cells[4].title !== s.fault) row.cells[4].title = s.fault;
    const rowClass = s.state === "fault" ? "fault" : "";
    if (row.className !== rowClass) row.className = rowClass;
  });
}

// Faults in the puppeteer's words (the kind and the bus's own detail on hover); events that are
// not faults (a servo back, settings restored) on a quieter list of their own.
function addFault(f) {
  const li = document.createElement("li");
  const servos = f.ids.length ? (f.ids.length > 1 ? "servos " : "servo ") + f.ids.join(", ") + ": " : "";
  li.textContent = `${f.t_s.toFixed(1)} s  ${servos}${f.words || f.kind}`;
  li.title = `${f.kind}${f.detail ? ": " + f.detail : ""}`;
  const list = $(f.fault === false ? "events" : "faults");
  list.prepend(li);
  while (list.children.length > MAX_FAULTS) list.lastChild.remove();
}

function showLegend(legend) {
  $("legend").replaceChildren(...legend.map(item => {
    const li = document.createElement("li");
    const swatch = document.createElement("span");
    swatch.className = "swatch"; swatch.style.background = item.color;
    li.append(swatch, `${item.state}: ${item.words}`);
    return li;
  }));
}

function setOverlay(on) { state.overlay = on; $("overlay").setAttribute("aria-pressed", String(on)); }

// r.changes: the recording's starts and stops so far; a panel sent before a start or stop can
// arrive after it (the panel goes after the messages): the older state is not shown over the
// newer (a stale "on" would make the button send stop instead of record). A snapshot is the
// server's word (a studio started again counts from 0).
function setRecording(r, snapshot = false) {
  if (!snapshot && r.changes !== undefined && state.recording.changes !== undefined &&
      r.changes < state.recording.changes) return;
  state.recording = r;
  const button = $("record");
  button.textContent = r.on ? "■ stop" : "● record";
  button.classList.toggle("recording", r.on);
  $("recording-state").textContent = r.on ? `recording ${r.path} (${r.readings ?? 0} readings)` :
    (r.path ? `last take: ${r.path}` : "");
}

function updatePlayback(p) {
  state.playback = p;
  const scrub = $("scrub");
  scrub.max = String(p.duration_s || 1);
  if (!scrubbing) scrub.value = String(p.position_s);
  $("clock").textContent = `${p.position_s.toFixed(1)} / ${p.duration_s.toFixed(1)} s`;
  $("pause").textContent = p.paused || atEnd(p) ? "play" : "pause";
  showTakeMarks(p.markers || [], p.duration_s || 1);
}

function atEnd(p) { return p.position_s >= p.duration_s - 1e-3; }

// The take's marks: ticks on the slider and a list; a click jumps there. Rebuilt only on change.
let takeMarksKey = "";
function showTakeMarks(markers, duration) {
  const key = JSON.stringify(markers);
  if (key === takeMarksKey) return;
  takeMarksKey = key;
  state.takeMarks = markers;
  $("take-marks").replaceChildren(...markers.map(m => {
    const option = document.createElement("option");
    option.value = String(Math.min(m.t_s, duration)); option.label = m.name;
    return option;
  }));
  $("take-mark-list").replaceChildren(...markers.map(m => {
    const li = document.createElement("li");
    const button = document.createElement("button");
    button.className = "take-mark";
    button.textContent = `${m.name} · ${m.t_s.toFixed(2)} s`;
    button.onclick = () => send({ type: "playback", action: "seek", value: m.t_s });
    li.append(button);
    return li;
  }));
}

// ---- marks drawn by the page (handles, the drag in progress) --------------------------------
let marksShown = false;  // anything on the marks canvas (clearing an empty one still repaints it)
function drawMarks() {
  const dragging = drag && drag.started && !drag.orbit && !drag.pan;
  if (!marksShown && !state.handleSpots.length && !dragging) return;
  marksShown = state.handleSpots.length > 0 || dragging;
  marks.style.opacity = marksShown ? "1" : "0";  // an empty layer is left out of compositing
  marksCtx.clearRect(0, 0, marks.width, marks.height);
  for (const spot of state.handleSpots) {
    if (drag && drag.handle === spot.id && !drag.orbit) continue;
    circle(spot.x, spot.y, "#ffd54a");
  }
  if (dragging) circle(drag.x, drag.y, drag.pending ? "#aaa" : "#ffd54a");
}

function circle(x, y, color) {
  marksCtx.beginPath();
  marksCtx.arc(x, y, HANDLE_RADIUS, 0, 2 * Math.PI);
  marksCtx.fillStyle = color; marksCtx.globalAlpha = 0.85; marksCtx.fill();
  marksCtx.globalAlpha = 1; marksCtx.lineWidth = 2; marksCtx.strokeStyle = "#222"; marksCtx.stroke();
}

// ---- input --------------------------------------------------------------------------------
let drag = null;
let nextKey = 1;
let moves = {};
let scrubbing = false;

function imagePoint(event) {
  const box = marks.getBoundingClientRect();
  return [(event.clientX - box.left) * marks.width / box.width, (event.clientY - box.top) * marks.height / box.height];
}

function handleAt(x, y) {
  let best = null, bestD = HANDLE_RADIUS + 4;
  for (const spot of state.handleSpots) {
    const d = Math.hypot(spot.x - x, spot.y - y);
    if (d <= bestD) { best = spot; bestD = d; }
  }
  return best;
}

// Camera moves and drags are sent at most once per animation frame (merged).
function queueMove(kind, dx, dy) {
  const m = moves[kind] || (moves[kind] = { dx: 0, dy: 0 });
  m.dx += dx; m.dy += dy;
  scheduleFlush();
}
let flushScheduled = false;
function scheduleFlush() {
  if (flushScheduled) return;
  flushScheduled = true;
  requestAnimationFrame(flush);
}
function flush() {
  flushScheduled = false;
  for (const [kind, m] of Object.entries(moves)) if (m.dx || m.dy) send({ type: kind, dx: m.dx, dy: m.dy });
  moves = {};
  if (drag && drag.dirty && !drag.orbit && !drag.pan) {
    send({ type: "drag", key: drag.key, x: drag.x, y: drag.y });
    drag.dirty = false;
  }
  drawMarks();
}

marks.addEventListener("pointerdown", event => {
  if (event.button === 2) return;
  marks.setPointerCapture(event.pointerId);
  const [x, y] = imagePoint(event);
  const key = nextKey++;
  drag = { key, x, y, startX: x, startY: y, lastX: x, lastY: y, dirty: false, pending: false,
           handle: null, orbit: false, pan: event.button === 1 || event.shiftKey,
           screenX: event.clientX, screenY: event.clientY, seq: Math.max(state.shownSeq, 0), started: false };
  if (drag.pan) return;
  const spot = handleAt(x, y);
  if (spot) {
    drag.handle = spot.id; drag.started = true;
    send({ type: "grab", key, handle: spot.id });
  }
  drawMarks();
});

// A press on the character becomes a pick (a new handle) only once it is a drag.
function startPick(event) {
  if (drag.started || Math.hypot(event.clientX - drag.screenX, event.clientY - drag.screenY) < PIN_DRAG_PX) return false;
  drag.started = true; drag.pending = true;
  send({ type: "pick", key: drag.key, seq: drag.seq, x: drag.startX, y: drag.startY });
  return true;
}

marks.addEventListener("pointermove", event => {
  if (!drag) return;
  const [x, y] = imagePoint(event);
  const dx = x - drag.lastX, dy = y - drag.lastY;
  drag.lastX = x; drag.lastY = y; drag.x = x; drag.y = y;
  if (drag.pan) queueMove("pan", dx, dy);
  else if (drag.orbit) queueMove("orbit", dx, dy);
  else if (drag.started || startPick(event)) { drag.dirty = true; scheduleFlush(); }
});

function endDrag() {
  if (drag && drag.started && drag.dirty && !drag.orbit && !drag.pan) send({ type: "drag", key: drag.key, x: drag.x, y: drag.y });
  drag = null;
  drawMarks();
}
marks.addEventListener("pointerup", endDrag);
marks.addEventListener("pointercancel", endDrag);

function removeAt(event) {
  const [x, y] = imagePoint(event);
  const spot = handleAt(x, y);
  if (spot) send({ type: "remove", handle: spot.id });
}
marks.addEventListener("contextmenu", event => { event.preventDefault(); removeAt(event); });
marks.addEventListener("dblclick", event => { event.preventDefault(); removeAt(event); });
marks.addEventListener("wheel", event => {
  event.preventDefault();
  send({ type: "zoom", factor: Math.exp(Math.max(-0.5, Math.min(0.5, event.deltaY * 0.001))) });
}, { passive: false });

// ---- keys: the Key button and Space, onion skins, the timeline ---------------------------------
const timeline = $("timeline");
const timelineCtx = timeline.getContext("2d");
const TICK_GRAB_PX = 8;     // a press this close to a key's tick (canvas px) grabs it
let tickDrag = null;        // {index, frame, from} while a tick is dragged

function timelineSpan() {
  const k = state.keys;
  const frames = k.keys.map(key => key.frame);
  return Math.max(k.next_frame, k.playhead, ...frames) + k.step;
}
function frameToX(frame) {
  const pad = 14, span = timelineSpan();
  return pad + (frame - 1) / Math.max(span - 1, 1) * (timeline.width - 2 * pad);
}
function xToFrame(x) {
  const pad = 14, span = timelineSpan();
  const f = 1 + (x - pad) / (timeline.width - 2 * pad) * Math.max(span - 1, 1);
  return Math.max(1, Math.round(f));
}
function timelinePoint(event) {
  const box = timeline.getBoundingClientRect();
  return (event.clientX - box.left) * timeline.width / box.width;
}
function drawTimeline() {
  const k = state.keys;
  if (!k) return;
  const ctx = timelineCtx, h = timeline.height;
  ctx.clearRect(0, 0, timeline.width, h);
  ctx.strokeStyle = "#555b66"; ctx.lineWidth = 1;
  ctx.beginPath(); ctx.moveTo(frameToX(1), h - 12); ctx.lineTo(frameToX(timelineSpan()), h - 12); ctx.stroke();
  ctx.fillStyle = "#9aa0aa"; ctx.font = "10px system-ui, sans-serif"; ctx.textAlign = "center";
  for (let f = 1; f <= timelineSpan(); f += k.step) ctx.fillText(String(f), frameToX(f), h - 1);
  const x = frameToX(k.playhead);
  ctx.strokeStyle = "#e2574c"; ctx.beginPath(); ctx.moveTo(x, 2); ctx.lineTo(x, h - 12); ctx.stroke();
  k.keys.forEach((key, i) => {
    const frame = tickDrag && tickDrag.index === i ? tickDrag.frame : key.frame;
    const kx = frameToX(frame);
    ctx.fillStyle = tickDrag && tickDrag.index === i ? "#ffd54a" : "#4c8ee2";
    ctx.fillRect(kx - 3, 12, 6, h - 26);
    if (state.selectedKey === i) { ctx.strokeStyle = "#ffffff"; ctx.strokeRect(kx - 5, 11, 10, h - 24); }
    ctx.fillStyle = "#e6e6e6"; ctx.fillText(String(key.index), kx, 10);  // its stable id
  });
}
function tickAt(x) {
  let best = null, bestD = TICK_GRAB_PX;
  state.keys.keys.forEach((key, i) => {
    const d = Math.abs(frameToX(key.frame) - x);
    if (d <= bestD) { best = i; bestD = d; }
  });
  return best;
}
timeline.addEventListener("pointerdown", event => {
  if (!state.keys) return;
  timeline.setPointerCapture(event.pointerId);
  const x = timelinePoint(event);
  const index = tickAt(x);
  if (index === null) { send({ type: "playhead", frame: xToFrame(x) }); return; }
  const frame = state.keys.keys[index].frame;
  tickDrag = { index, frame, from: frame };
  drawTimeline();
});
timeline.addEventListener("pointermove", event => {
  if (!tickDrag) return;
  tickDrag.frame = xToFrame(timelinePoint(event));
  drawTimeline();
});
function endTickDrag() {
  if (!tickDrag) return;
  const { index, frame, from } = tickDrag;
  tickDrag = null;
  if (frame !== from) send({ type: "retime", index: state.keys.keys[index].index, frame });  // by its id; the file is rewritten by puppet, then the ticks redrawn
  else state.selectedKey = state.selectedKey === index ? null : index;  // a click on a tick (de)selects it
  showSelectedKey();
}
// The key buttons edit the selected key: enabled with one, its interpolation shown.
function showSelectedKey() {
  const k = state.keys, i = state.selectedKey;
  const key = k && i !== null ? k.keys[i] : null;
  $("key-replace").disabled = $("key-delete").disabled = !key;
  $("key-interpolation").value = key ? key.interpolation : (k ? k.interpolation : "linear");
  drawTimeline();
}
// A key edit goes to puppet as the terminal's command line for it (the same KeyDesk).
function keyEdit(action) {
  const k = state.keys;
  if (!k) return;
  send({ type: "key_edit", action, index: state.selectedKey === null ? 0 : k.keys[state.selectedKey].index,
         frame: k.playhead, interpolation: $("key-interpolation").value });
}
timeline.addEventListener("pointerup", endTickDrag);
timeline.addEventListener("pointercancel", endTickDrag);
// Where a frame lies on the timeline, in page coordinates (tests drag ticks with it).
state.timelineAt = frame => {
  const box = timeline.getBoundingClientRect();
  return { x: box.left + frameToX(frame) * box.width / timeline.width, y: box.top + box.height / 2 - 6 };
};

$("key").onclick = () => send({ type: "key" });
$("key-replace").onclick = () => keyEdit("replace");
$("key-delete").onclick = () => { keyEdit("delete"); state.selectedKey = null; showSelectedKey(); };
$("key-insert").onclick = () => keyEdit("insert");
// With a key selected: its interpolation; without: that of the keys to come.
$("key-interpolation").onchange = () => keyEdit(state.selectedKey === null ? "new_interpolation" : "interpolation");
$("onion").onclick = () => send({ type: "onion", on: !(state.keys && state.keys.onion) });
document.addEventListener("keydown", event => {
  if (event.code !== "Space" || !state.keys || event.repeat) return;
  const tag = event.target && event.target.tagName;
  if (tag === "INPUT" || tag === "SELECT" || tag === "TEXTAREA") return;
  event.preventDefault();  // not a scroll
  send({ type: "key" });
});
document.addEventListener("keyup", event => {  // a focused button would be clicked on Space's keyup
  if (event.code !== "Space" || !state.keys) return;
  const tag = event.target && event.target.tagName;
  if (tag !== "INPUT" && tag !== "SELECT" && tag !== "TEXTAREA") event.preventDefault();
});

$("overlay").onclick = () => send({ type: "overlay", on: !state.overlay });
document.querySelectorAll("[data-preset]").forEach(b => { b.onclick = () => send({ type: "preset", name: b.dataset.preset }); });
$("reset").onclick = () => send({ type: "reset" });
$("own").onclick = () => {
  state.ownCamera = !state.ownCamera;
  $("own").setAttribute("aria-pressed", String(state.ownCamera));
  send({ type: "camera_mode", own: state.ownCamera });
};
$("record").onclick = () => send({ type: "record", on: !state.recording.on });
$("marker").onclick = () => send({ type: "marker", name: ($("marker-name").value || "mark").slice(0, 80) });
// At the end (e.g. scrubbed there) the button plays from the start, whatever the last panel said.
$("pause").onclick = () => {
  const p = state.playback;
  send({ type: "playback", action: p && (p.paused || atEnd(p)) ? "play" : "pause", value: 0 });
};
$("scrub").addEventListener("input", () => { scrubbing = true; send({ type: "playback", action: "seek", value: Number($("scrub").value) }); });
$("scrub").addEventListener("change", () => { scrubbing = false; });
$("speed").onchange = () => send({ type: "playback", action: "speed", value: Number($("speed").value) });

setInterval(() => {
  const t = state.shownTimes;
  while (t.length && performance.now() - t[0] > 2000) t.shift();
  state.fps = t.length > 1 ? (t.length - 1) * 1000 / (t[t.length - 1] - t[0]) : 0;
  $("fps").textContent = state.fps.toFixed(0);
}, 500);

// Connect once every script of the page has run: the studio's (studio.js, after this one) extends
// the handlers, and a snapshot that arrived while it was still loading went to the plain view's
// (the page then never showed its studio).
function connect() { connectControl(); connectFrames(); }
if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", connect);
else connect();
