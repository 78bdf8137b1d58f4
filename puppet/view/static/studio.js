// puppet studio: the session's shots and numbered takes beside the live view (view.js): record
// with a count-in, review (play, pause, scrub, speed), circle, note, lock, trash, clips, export.
// Every change goes to the server as {type: "studio", action, ...}; the server answers every page
// with the session's listing ({type: "studio", shots: [...], said, reviewing, export}).
"use strict";

Object.assign(state, { studio: null, selected: null, clip: { in_s: null, out_s: null }, countdownTimer: null,
                       layerJoints: new Set(), shownJoints: "", pickJoints: false, layerPress: null });

function studioSend(action, fields) { send({ type: "studio", action, ...(fields || {}) }); }

function currentShot() {
  const s = state.studio;
  return s && s.shots.find(shot => shot.key === s.current_shot) || null;
}

function selectedTake() {
  const sel = state.selected, s = state.studio;
  if (!sel || !s) return null;
  const shot = s.shots.find(x => x.key === sel.shot);
  const take = shot && shot.takes.find(t => t.number === sel.take);
  return take ? { shot, take } : null;
}

// "layer over take 3": a layer take names its base (another shot's or a file's when elsewhere)
function layerOver(take) {
  if (!take.layer_over) return null;
  for (const shot of (state.studio && state.studio.shots) || []) {
    const base = shot.takes.find(t => t.file === take.layer_over);
    if (base) return shot.key === take.file.split("/")[1] ? `layer over take ${base.number}`
      : `layer over ${shot.name} take ${base.number}`;
  }
  return `layer over ${take.layer_over}`;
}

function takeLine(take) {
  const flags = [];
  const layer = layerOver(take);
  if (layer) flags.push(layer);
  if (take.circled) flags.push("circled");
  if (take.locked) flags.push("locked");
  if (take.status !== "ok") flags.push(take.status);
  const duration = take.duration_s == null ? "?" : `${take.duration_s.toFixed(1)} s`;
  const date = (take.date || "").replace("T", " ").replace(/\.\d+/, "").replace("Z", "");
  return { head: `take ${take.number}`, facts: `${date} · ${take.rig || "?"} · ${duration}`,
           flags: flags.join(" · "), note: take.note || "" };
}

function renderStudio() {
  const s = state.studio;
  if (!s) return;
  const shotSelect = $("shot");
  shotSelect.replaceChildren(...s.shots.map(shot => {
    const o = document.createElement("option");
    o.value = shot.key; o.textContent = shot.name; o.selected = shot.key === s.current_shot;
    return o;
  }));
  const soundSelect = $("sound-file");
  const chosen = s.sound ? s.sound.name : "";
  const names = Array.from(new Set([...(s.sounds || []), ...(chosen ? [chosen] : [])]));
  soundSelect.replaceChildren(new Option("none", ""), ...names.map(n => new Option(n, n, false, n === chosen)));
  soundSelect.value = chosen;
  soundSelect.disabled = state.recording.on;
  const shot = currentShot();
  if (state.selected && !selectedTake()) state.selected = null;
  const list = $("takes");
  const rows = shot ? shot.takes.map(take => {
    const li = document.createElement("li");
    const t = takeLine(take);
    const button = document.createElement("button");
    button.className = "take";
    const chosen = state.selected && state.selected.shot === shot.key && state.selected.take === take.number;
    button.setAttribute("aria-pressed", String(!!chosen));
    button.classList.toggle("trashed", take.trashed);
    button.classList.toggle("missing", take.status.includes("missing"));
    button.setAttribute("aria-label", `${shot.name} take ${take.number}${t.flags ? ", " + t.flags : ""}`);
    const head = document.createElement("b"); head.textContent = t.head;
    const facts = document.createElement("span"); facts.className = "facts"; facts.textContent = t.facts;
    const flags = document.createElement("span"); flags.className = "flags"; flags.textContent = t.flags;
    const note = document.createElement("span"); note.className = "take-note"; note.textContent = t.note;
    button.append(head, facts, flags, note);
    if (take.segments && take.segments.length) {
      const segs = document.createElement("span"); segs.className = "facts clips";
      segs.textContent = "clips: " + take.segments.map(x => `${x.name}${x.loop ? " (loop)" : ""}`).join(", ");
      button.append(segs);
    }
    button.onclick = () => { state.selected = { shot: shot.key, take: take.number }; renderStudio(); };
    li.append(button);
    return li;
  }) : [];
  list.replaceChildren(...rows);
  if (!rows.length) {
    const li = document.createElement("li"); li.className = "empty";
    li.textContent = shot ? "no takes yet: press record" : "no shot yet: name one and press new shot";
    list.append(li);
  }
  const sel = selectedTake();
  const take = sel && sel.take;
  const usable = take && !take.trashed;
  const editable = usable && !take.locked;
  $("review").disabled = !usable || take.status !== "ok" || state.recording.on;
  $("go-live").disabled = !s.reviewing;
  const reviewed = s.reviewing && sel && sel.shot.key === s.reviewing.shot && take.number === s.reviewing.take;
  $("compare").disabled = !s.reviewing || !usable || take.status !== "ok" || !!reviewed;
  $("compare-off").disabled = !s.comparing;
  $("circle").disabled = !editable;
  $("circle").setAttribute("aria-pressed", String(!!(take && take.circled)));
  $("circle").textContent = take && take.circled ? "uncircle" : "circle";
  $("lock").disabled = !usable;
  $("lock").setAttribute("aria-pressed", String(!!(take && take.locked)));
  $("lock").textContent = take && take.locked ? "unlock" : "lock";
  $("delete").disabled = !editable;
  $("restore").disabled = !(take && take.trashed);
  $("save-note").disabled = !editable;
  $("note").disabled = !editable;
  if (take && document.activeElement !== $("note")) $("note").value = take.note || "";
  $("rename-shot").disabled = !shot;
  $("export-take").disabled = !usable || take.status !== "ok" || !!(s.export && s.export.running);
  const anyCircled = s.shots.some(x => x.takes.some(t => t.circled && !t.trashed));
  $("export-circled").disabled = !anyCircled || !!(s.export && s.export.running);
  const ex = s.export;
  const bar = $("export-progress");
  if (ex) { bar.max = ex.total || 1; bar.value = ex.running ? (ex.done || 0) : ex.total || 1; }
  const said = $("studio-said");
  said.textContent = s.said ? s.said.text : " ";
  said.classList.toggle("refused", !!(s.said && !s.said.ok));
  $("keys-start").disabled = !!s.keying || state.recording.on;
  $("keys-done").disabled = !s.keying;
  $("record").disabled = !!s.keying;
  renderLayerBox(s, take, usable);
  $("keys").hidden = !s.keying;
  if (!s.keying) state.keys = null;
  const reviewing = !!s.reviewing;
  $("playback").hidden = !reviewing;
  $("clip-bar").hidden = !reviewing;
  showClip();
  showInstruction();
}

function showGhostLegend(legend) {
  $("onion-legend").replaceChildren(...legend.map(item => {
    const li = document.createElement("li");
    const swatch = document.createElement("span");
    swatch.className = "swatch"; swatch.style.background = item.color;
    li.append(swatch, document.createTextNode(item.what));
    return li;
  }));
  $("onion-legend").hidden = false;
}

function showClip() {
  const c = state.clip;
  const fmt = v => v == null ? "–" : `${v.toFixed(2)} s`;
  $("clip-span").textContent = `in ${fmt(c.in_s)} · out ${fmt(c.out_s)}`;
  const sel = selectedTake();
  const ok = c.in_s != null && c.out_s != null && c.out_s > c.in_s && state.studio && state.studio.reviewing
    && sel && !sel.take.locked;
  $("clip-make").disabled = !ok;
}

// "Record a layer": a tick box per joint the layer can hold; the selected take is its base.
function renderLayerBox(s, take, usable) {
  const joints = s.joints || [];
  if (state.shownJoints !== joints.join(",")) {
    state.shownJoints = joints.join(",");
    $("layer-joints").replaceChildren(...joints.map(name => {
      const label = document.createElement("label");
      const box = document.createElement("input");
      box.type = "checkbox"; box.value = name; box.setAttribute("aria-label", `layer joint ${name}`);
      box.checked = state.layerJoints.has(name);
      box.onchange = () => { if (box.checked) state.layerJoints.add(name); else state.layerJoints.delete(name); renderStudio(); };
      label.append(box, document.createTextNode(` ${name}`));
      return label;
    }));
  }
  $("layer-joints").querySelectorAll("input").forEach(box => { box.checked = state.layerJoints.has(box.value); });
  const button = $("record-layer");
  button.disabled = !usable || take.status !== "ok" || !state.layerJoints.size || state.recording.on || !!s.keying;
  button.textContent = take ? `● record a layer over take ${take.number}` : "● record a layer";
}

// One line that says what to do now, for the current mode.
function showInstruction() {
  const s = state.studio, r = state.recording;
  let text;
  if (!s) return;
  if (r.on && r.starts_in_s > 0) text = "Count-in: get ready, recording starts at 0.";
  else if (r.on && s.layering) text = `Recording a layer over take ${s.layering.take}: the base plays; perform ${s.layering.joints.join(", ")} now, stop when done.`;
  else if (r.on) text = "Recording: perform now; press marker to mark a moment, stop when done.";
  else if (s.keying) text = "Key poses: hold the puppet still in a pose and press Space (or key); press done keys when the shot is posed.";
  else if (s.comparing) text = "Comparing: the magenta ghost is the other take at the same time; play or scrub to see both.";
  else if (s.reviewing) text = "Reviewing a take: play, pause, scrub and speed below; set in and out to make a clip; live goes back to the puppet.";
  else if (!currentShot()) text = "Name a shot and press new shot, then record.";
  else if (state.selected) text = "Take selected: review it, circle the good ones, add a note, lock it or delete it; or record the next take.";
  else text = `Live: press record to record the next take of "${currentShot().name}" after the count-in; pick a take to review it.`;
  const el = $("instruction");
  if (el.textContent !== text) el.textContent = text;
}

function showCountdown() {
  const r = state.recording, el = $("countdown");
  clearInterval(state.countdownTimer);
  if (!r.on || !(r.starts_in_s > 0)) { el.hidden = true; return; }
  const zero = performance.now() + r.starts_in_s * 1000;
  const tick = () => {
    const left = (zero - performance.now()) / 1000;
    if (left <= 0) { el.hidden = true; clearInterval(state.countdownTimer); showInstruction(); return; }
    el.hidden = false; el.textContent = String(Math.ceil(left));
  };
  tick();
  state.countdownTimer = setInterval(tick, 100);
}

const viewSnapshot = handlers.snapshot;
handlers.snapshot = m => {
  viewSnapshot(m);
  if (!m.studio) return;
  document.body.classList.add("studio-mode");
  $("studio").hidden = false;
  $("instruction").hidden = false;
  $("count-in-label").hidden = false;
  $("hint").hidden = true;
  handlers.studio(m.studio);
  showGhostLegend(m.ghost_legend || []);
  (m.studio.notes || []).forEach(text => note(`session: ${text}`));
};
handlers.studio = m => { state.studio = m; renderStudio(); };
const viewRecording = handlers.recording;
handlers.recording = m => { viewRecording(m); if (state.studio) { showCountdown(); renderStudio(); } };
const viewPanel = handlers.panel;
handlers.panel = m => {
  const wasOn = state.recording.on;
  viewPanel(m);
  if (state.studio && wasOn !== state.recording.on) renderStudio();
};

$("record").onclick = () => {
  if (!state.studio) { send({ type: "record", on: !state.recording.on }); return; }
  if (state.recording.on) studioSend("stop");
  else studioSend("record", { count_in: Number($("count-in").value) });
};
$("record-layer").onclick = () => onSelected("record_layer", { count_in: Number($("count-in").value),
  joints: (state.studio.joints || []).filter(name => state.layerJoints.has(name)) });
// "pick on the figure": a plain click (no drag) on the character ticks the joint under it
$("pick-joints").onclick = () => {
  state.pickJoints = !state.pickJoints;
  $("pick-joints").setAttribute("aria-pressed", String(state.pickJoints));
};
marks.addEventListener("pointerdown", event => {
  state.layerPress = state.pickJoints && event.button === 0 && !event.shiftKey
    ? { x: event.clientX, y: event.clientY, at: imagePoint(event), seq: Math.max(state.shownSeq, 0) } : null;
});
marks.addEventListener("pointerup", event => {
  const p = state.layerPress;
  state.layerPress = null;
  if (!p || !state.pickJoints || Math.hypot(event.clientX - p.x, event.clientY - p.y) >= PIN_DRAG_PX) return;
  studioSend("pick_joint", { x: p.at[0], y: p.at[1], seq: p.seq });
});
handlers.layer_joint = m => {
  if (state.layerJoints.has(m.joint)) state.layerJoints.delete(m.joint); else state.layerJoints.add(m.joint);
  renderStudio();
};
$("new-shot").onclick = () => studioSend("new_shot", { name: $("shot-name").value });
$("rename-shot").onclick = () => { const s = currentShot(); if (s) studioSend("rename_shot", { shot: s.key, name: $("shot-name").value }); };
$("shot").onchange = () => { state.selected = null; studioSend("use_shot", { shot: $("shot").value }); };
function onSelected(action, fields) {
  const sel = selectedTake();
  if (sel) studioSend(action, { shot: sel.shot.key, take: sel.take.number, ...(fields || {}) });
}
$("review").onclick = () => { state.clip = { in_s: null, out_s: null }; onSelected("review"); };
$("go-live").onclick = () => studioSend("live");
$("keys-start").onclick = () => studioSend("keys_start");
$("keys-done").onclick = () => studioSend("keys_done");
$("sound-file").onchange = () => studioSend("sound", { name: $("sound-file").value });
$("compare").onclick = () => onSelected("compare");
$("compare-off").onclick = () => studioSend("compare_off");
$("circle").onclick = () => { const sel = selectedTake(); if (sel) onSelected("circle", { on: !sel.take.circled }); };
$("lock").onclick = () => { const sel = selectedTake(); if (sel) onSelected("lock", { on: !sel.take.locked }); };
$("delete").onclick = () => onSelected("delete");
$("restore").onclick = () => onSelected("restore");
$("save-note").onclick = () => onSelected("note", { text: $("note").value });
$("clip-in").onclick = () => { state.clip.in_s = state.playback ? state.playback.position_s : 0; showClip(); };
$("clip-out").onclick = () => { state.clip.out_s = state.playback ? state.playback.position_s : 0; showClip(); };
$("clip-make").onclick = () => {
  const r = state.studio.reviewing;
  studioSend("segment", { shot: r.shot, take: r.take, name: $("clip-name").value || "clip",
                          in_s: state.clip.in_s, out_s: state.clip.out_s, loop: $("clip-loop").checked });
};
function exportFields(scope) {
  const formats = Array.from(document.querySelectorAll("input[name=format]:checked"), x => x.value);
  const fps = $("export-fps").value === "" ? null : Number($("export-fps").value);
  const keys = $("export-keys").value === "" ? null : Number($("export-keys").value);
  return { scope, formats, fps, keys };
}
$("export-take").onclick = () => onSelected("export", exportFields("take"));
$("export-circled").onclick = () => studioSend("export", exportFields("circled"));

// ---- the shot's sound: waveform under the timeline, Web Audio from the take's time 0 ----------
// The page plays the sound file the studio serves (/sound): from the count-in's end while
// recording (its offset at the take's time 0), from the play position in review (at its speed),
// and a short piece under the playhead while scrubbing (lip sync).
const SCRUB_PIECE_S = 0.15;
const audio = { ctx: null, buffer: null, loading: null, source: null, starts: [], playingReview: false };
state.audio = audio;

function audioContext() {
  if (!audio.ctx) audio.ctx = new AudioContext({ latencyHint: "interactive" });
  if (audio.ctx.state === "suspended") audio.ctx.resume();
  return audio.ctx;
}
function loadSound() {
  const s = state.studio;
  if (s && s.sound && audio.sha !== s.sound.sha256) { audio.sha = s.sound.sha256; audio.loading = null; audio.buffer = null; }
  if (audio.loading || !(s && s.sound)) return audio.loading;
  const url = "sound" + (token ? `?token=${encodeURIComponent(token)}` : "");
  audio.loading = fetch(url).then(r => { if (!r.ok) throw new Error(`sound: ${r.status}`); return r.arrayBuffer(); })
    .then(data => audioContext().decodeAudioData(data))
    .then(buffer => { audio.buffer = buffer; drawWaveform(); })
    .catch(err => note(`sound: cannot be played here (${err.message})`));
  return audio.loading;
}
function stopSound() {
  if (audio.source) { try { audio.source.stop(); } catch (e) { /* already stopped */ } audio.source = null; }
}
// The context time heard at frame-clock time at_ms (performance.now's): the output timestamp
// maps one clock onto the other, output latency included (bench/sound.py: ctx.currentTime + delay
// is heard ~40 ms late in Chromium); ctx.currentTime + delay until the context runs.
function heardAt(ctx, at_ms) {
  const ts = ctx.getOutputTimestamp();
  if (ctx.state !== "running" || !(ts.performanceTime > 0)) {
    return ctx.currentTime + (at_ms - performance.now()) / 1000;
  }
  return ts.contextTime + (at_ms - ts.performanceTime) / 1000;
}
// offset_s: where in the sound; delay_s: from now; rate: speed; piece_s: how long (null: to its end)
function playSound(offset_s, delay_s, rate, piece_s) {
  if (!audio.buffer) return;
  stopSound();
  const ctx = audioContext();
  const source = ctx.createBufferSource();
  source.buffer = audio.buffer;
  source.playbackRate.value = rate || 1;
  source.connect(ctx.destination);
  let when = heardAt(ctx, performance.now() + Math.max(0, delay_s) * 1000);
  if (offset_s < 0) { when += -offset_s / (rate || 1); offset_s = 0; }
  when = Math.max(when, ctx.currentTime);  // (a time already past: as soon as it can)
  if (offset_s >= audio.buffer.duration) return;
  source.start(when, offset_s, piece_s == null ? undefined : piece_s);
  audio.source = source;
  audio.starts.push({ when, offset_s, rate: rate || 1, piece_s, now: ctx.currentTime });
  if (audio.starts.length > 100) audio.starts.shift();
}
function soundOffset() {
  const s = state.studio;
  if (!s || !s.sound) return null;
  if (s.reviewing) return s.reviewing.sound_offset_s;
  return s.sound.offset_s;
}
function soundPosition() {
  const s = state.studio, r = state.recording, offset = soundOffset();
  if (offset == null) return null;
  if (s.reviewing && state.playback) return offset + state.playback.position_s;
  if (r.on && audio.recordZero != null) return offset + Math.max(0, (performance.now() - audio.recordZero) / 1000);
  return offset;
}
function drawWaveform() {
  const s = state.studio, canvas = $("waveform");
  if (!s || !s.sound) { canvas.hidden = true; return; }
  canvas.hidden = false;
  const ctx = canvas.getContext("2d"), w = canvas.width, h = canvas.height, peaks = s.sound.peaks;
  ctx.fillStyle = "#25282f"; ctx.fillRect(0, 0, w, h);
  ctx.fillStyle = "#b8c4d6";
  for (let x = 0; x < w; x++) {
    const p = peaks[Math.floor(x * peaks.length / w)];
    const y0 = (1 - p[1]) * h / 2, y1 = (1 - p[0]) * h / 2;
    ctx.fillRect(x, y0, 1, Math.max(1, y1 - y0));
  }
  const at = soundPosition();
  if (at != null) {
    const x = Math.round(at / s.sound.duration_s * w);
    ctx.fillStyle = "#ff3b30"; ctx.fillRect(Math.min(x, w - 2), 0, 2, h);
  }
}
function followSound() {  // the review's play, pause and speed, heard
  const s = state.studio, p = state.playback;
  if (!s || !s.reviewing || !p) { if (audio.playingReview) { stopSound(); audio.playingReview = false; } return; }
  const playing = !p.paused && p.position_s < p.duration_s - 1e-3;
  const offset = soundOffset();
  if (offset == null) return;
  if (playing && (!audio.playingReview || audio.reviewRate !== p.speed)) {
    playSound(offset + p.position_s, 0, p.speed, null);
    audio.playingReview = true; audio.reviewRate = p.speed;
  } else if (!playing && audio.playingReview) {
    stopSound(); audio.playingReview = false;
  }
}
document.addEventListener("pointerdown", () => { if (state.studio && state.studio.sound) { audioContext(); loadSound(); } }, true);
const studioWithSound = handlers.studio;
handlers.studio = m => { studioWithSound(m); if (m.sound) loadSound(); drawWaveform(); followSound(); };
const recordingWithSound = handlers.recording;
handlers.recording = m => {
  const was = state.recording.on;
  recordingWithSound(m);
  if (!state.studio || !state.studio.sound) return;
  if (m.on && !was) {
    audio.recordZero = performance.now() + (m.starts_in_s || 0) * 1000;
    playSound(state.studio.sound.offset_s, m.starts_in_s || 0, 1, null);  // heard from the take's time 0
  } else if (!m.on && was) { stopSound(); audio.recordZero = null; }
};
const panelWithSound = handlers.panel;
handlers.panel = m => { panelWithSound(m); if (state.studio && state.studio.sound) { followSound(); drawWaveform(); } };
$("scrub").addEventListener("input", () => {  // the sound under the playhead
  const offset = soundOffset();
  if (offset == null || !state.studio.reviewing) return;
  audio.playingReview = false;
  playSound(offset + Number($("scrub").value), 0, 1, SCRUB_PIECE_S);
});
