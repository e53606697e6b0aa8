// sdictl view's page: draws the frames sdictl sends over the WebSocket and
// drives sdid through sdictl's /api routes. Plots are plain canvas (three
// line/bar plots do not need a library). The statistics arrive computed
// (cli/src/view/analysis.rs); the page only draws them.
"use strict";
// The token arrives in the URL's fragment (sdictl's redirect file), which
// the browser never sends; it is kept in this tab's session storage (this
// origin's only) and dropped from the address bar and the tab's history.
const token = (() => {
  const given = new URLSearchParams(location.hash.slice(1)).get("token")
    || new URLSearchParams(location.search).get("token");
  if (given) {
    sessionStorage.setItem("sdi-token", given);
    history.replaceState(null, "", location.pathname);
    return given;
  }
  return sessionStorage.getItem("sdi-token") || "";
})();
const q = "?token=" + encodeURIComponent(token);
const $ = (id) => document.getElementById(id);
// What the tests and the benchmark read: the last frame's metadata and the
// page's own counters.
const state = window.sdiView = { meta: null, shown: 0, fps: 0, status: null };

async function api(path, body) {
  const opts = body === undefined ? {} : {
    method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify(body),
  };
  const r = await fetch("/api/" + path + q, opts);
  const json = await r.json();
  if (!r.ok) throw json;
  return json;
}

function showError(id, e) { $(id).textContent = e ? (e.message || String(e)) : ""; }

// ---- frames ----
let ws;
let frameTimes = [];
function connect() {
  ws = new WebSocket("ws://" + location.host + "/ws" + q);
  ws.binaryType = "arraybuffer";
  ws.onmessage = (ev) => drawFrame(ev.data);
  ws.onclose = () => { $("counters").textContent = "disconnected"; setTimeout(connect, 1000); };
}

function drawFrame(buf) {
  const len = new DataView(buf).getUint32(0, true);
  const meta = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, len)));
  let off = 4 + len;
  for (const im of meta.images) {
    const n = im.width * im.height * 4;
    const c = $(im.name);
    if (c.width !== im.width || c.height !== im.height) { c.width = im.width; c.height = im.height; }
    c.getContext("2d").putImageData(new ImageData(new Uint8ClampedArray(buf, off, n), im.width, im.height), 0, 0);
    off += n;
  }
  $("channels").style.display = meta.images.length > 1 ? "flex" : "none";
  if (meta.channels_se_electrons) {
    const se = (v) => `± ${v == null ? "?" : v.toFixed(1)} e- (median standard error)`;
    $("i_plus_err").textContent = se(meta.channels_se_electrons[0]);
    $("i_minus_err").textContent = se(meta.channels_se_electrons[1]);
  }
  state.meta = meta;
  state.shown += 1;
  const now = performance.now();
  frameTimes.push(now);
  while (frameTimes.length && now - frameTimes[0] > 1000) frameTimes.shift();
  state.fps = frameTimes.length;
  $("counters").textContent = `frame ${meta.sequence} · ${meta.mode} · shown ${state.fps} fps · stream dropped ${meta.dropped} · saturated ${meta.saturated} px`;
  drawHistogram(meta.histogram);
  drawProbe(meta.probe);
  drawRegion(meta.region);
}

function plotFrame(c) {
  const g = c.getContext("2d");
  g.fillStyle = "#111"; g.fillRect(0, 0, c.width, c.height);
  return g;
}

function drawHistogram(h) {
  const c = $("histogram"), g = plotFrame(c);
  const max = Math.max(1, ...h.counts), bw = c.width / h.counts.length;
  g.fillStyle = "#8ab";
  h.counts.forEach((n, i) => { const y = n / max * (c.height - 4); g.fillRect(i * bw, c.height - y, bw - 1, y); });
  if (h.lo < 0 && h.hi > 0) { g.fillStyle = "#f80"; g.fillRect((-h.lo) / (h.hi - h.lo) * c.width, 0, 1, c.height); }
  $("histogram_range").textContent = `${h.lo.toFixed(1)} … ${h.hi.toFixed(1)} DN`;
}

function drawProbe(p) {
  const c = $("probe"), g = plotFrame(c);
  if (!p || !p.values.length) { $("probe_text").textContent = ""; return; }
  const lo = Math.min(...p.values), hi = Math.max(...p.values), span = hi - lo || 1;
  g.strokeStyle = "#8d8"; g.beginPath();
  p.values.forEach((v, i) => {
    const x = i / 119 * c.width, y = c.height - 4 - (v - lo) / span * (c.height - 8);
    i ? g.lineTo(x, y) : g.moveTo(x, y);
  });
  g.stroke();
  const m = p.moments;
  $("probe_text").textContent = `pixel (${p.x}, ${p.y}): ${m.n} frames, mean ${m.mean.toFixed(2)} DN, variance ${m.variance.toFixed(2)} DN²`;
}

function drawRegion(r) {
  const c = $("ptc"), g = plotFrame(c);
  if (!r || !r.report.points.length) { $("ptc_text").textContent = ""; return; }
  const pts = r.report.points;
  const xmax = Math.max(...pts.map((p) => p[0])) || 1, ymax = Math.max(...pts.map((p) => p[1])) || 1;
  const X = (x) => x / xmax * (c.width - 8) + 4, Y = (y) => c.height - 4 - y / ymax * (c.height - 8);
  g.fillStyle = "#8ab";
  for (const [x, y] of pts) g.fillRect(X(x) - 1, Y(y) - 1, 2, 2);
  const f = r.report.fit;
  if (f) {
    g.strokeStyle = "#f80"; g.beginPath(); g.moveTo(X(0), Y(f.intercept)); g.lineTo(X(xmax), Y(f.slope * xmax + f.intercept)); g.stroke();
  }
  $("ptc_text").textContent = `${pts.length} pixels over ${r.report.frames} frames` +
    (f ? `: variance = ${f.slope.toFixed(4)} · |mean| + ${f.intercept.toFixed(2)} DN² (slope ≈ gain, intercept ≈ read variance)` : "");
}

// probe: click; region: shift-drag
let dragFrom = null;
function pixelAt(ev) {
  const c = $("view"), r = c.getBoundingClientRect();
  return [Math.floor((ev.clientX - r.left) / r.width * c.width), Math.floor((ev.clientY - r.top) / r.height * c.height)];
}
$("view").addEventListener("mousedown", (ev) => { dragFrom = ev.shiftKey ? pixelAt(ev) : null; });
$("view").addEventListener("mouseup", (ev) => {
  const [x, y] = pixelAt(ev);
  if (dragFrom) {
    const x0 = Math.min(x, dragFrom[0]), y0 = Math.min(y, dragFrom[1]);
    ws.send(JSON.stringify({ region: [x0, y0, Math.abs(x - dragFrom[0]) + 1, Math.abs(y - dragFrom[1]) + 1] }));
  } else {
    ws.send(JSON.stringify({ probe: [x, y] }));
  }
  dragFrom = null;
});

// ---- status, modes, controls ----
async function setSetting(setting, value, errorId) {
  showError(errorId, null);
  try { await api("set", { setting, value: String(value) }); await refresh(); } catch (e) { showError(errorId, e); }
}

function buildModes(modes, setting) {
  const box = $("modes");
  box.textContent = "";
  for (const m of modes) {
    const b = document.createElement("button");
    b.id = "mode-" + m.name;
    b.innerHTML = `<b></b><div class="setup"></div>`;
    b.firstChild.textContent = m.name;
    b.lastChild.textContent = `LS1 ${m.ls1}; LS2 ${m.ls2}; optics ${m.optics}`;
    b.onclick = () => setSetting(setting.name, m.name, "mode_error");
    box.appendChild(b);
  }
}

// The settings' controls, from the table sdictl serves (status's
// "settings", sdi_api's Setting): the page names no setting itself. Each is
// a number input or a choice with the setting's name as its id, then (a
// number) its valid range and its error.
function buildSettings(settings) {
  const box = $("settings");
  box.textContent = "";
  for (const s of settings) {
    const label = document.createElement("label");
    label.textContent = s.label;
    let input;
    if (s.kind === "choice") {
      input = document.createElement("select");
      for (const c of s.choices) {
        const o = document.createElement("option");
        o.textContent = c;
        input.appendChild(o);
      }
    } else {
      input = document.createElement("input");
      input.type = "number";
      input.step = "any";
    }
    input.id = s.name;
    input.onchange = () => setSetting(s.name, input.value, s.name + "_error");
    label.appendChild(input);
    box.appendChild(label);
    for (const kind of s.kind === "number" ? ["valid", "error"] : ["error"]) {
      const d = document.createElement("div");
      d.className = kind;
      d.id = s.name + "_" + kind;
      box.appendChild(d);
    }
  }
}

// The valid range of each numeric control, as sdid reports it (its Limits,
// constant while sdid runs): bounds on the input and shown under it. A value
// outside still goes to sdid, whose typed error shows in place.
function showRanges(settings, ranges) {
  const num = (v) => String(Number(v.toPrecision(6)));
  for (const { name: id, kind } of settings) {
    if (kind !== "number") continue;
    const r = ranges[id];
    if (r) { $(id).min = r[0]; $(id).max = r[1]; } else { $(id).removeAttribute("min"); $(id).removeAttribute("max"); }
    $(id + "_valid").textContent = r ? `valid ${num(r[0])} to ${num(r[1])}` : "";
  }
}

let built = false;
async function refresh() {
  let s;
  try { s = await api("status"); } catch (e) { return; }
  state.status = s;
  const p = s.properties;
  if (!built) {
    buildModes(s.modes, s.mode_setting);
    buildSettings(s.settings);
    built = true;
  }
  showRanges(s.settings, s.ranges);
  const mode = p[s.mode_setting.property];
  for (const b of document.querySelectorAll(".modes button")) b.classList.toggle("current", b.id === "mode-" + mode);
  for (const { name, property } of s.settings) if (document.activeElement !== $(name)) $(name).value = p[property];
  // Stats: every key sdid sends, so fields added to Stats show up here.
  const t = $("stats");
  t.textContent = "";
  for (const [k, v] of Object.entries(p.Stats)) {
    const tr = t.insertRow();
    tr.insertCell().textContent = k;
    tr.insertCell().textContent = typeof v === "number" && !Number.isInteger(v) ? v.toFixed(2) : String(v);
  }
  $("record").textContent = p.Recording ? "Stop recording" : "Record";
  $("files_text").textContent = s.recording_path ? `recording ${s.recording_path}: ${s.recording_bytes ?? 0} bytes` : "";
}

async function snapshot(format) {
  showError("files_error", null);
  try { const r = await api("snapshot", { format }); $("files_text").textContent = "saved " + r.path; } catch (e) { showError("files_error", e); }
}
$("snap_png").onclick = () => snapshot("png");
$("snap_npy").onclick = () => snapshot("npy");
$("record").onclick = async () => {
  showError("files_error", null);
  try { await api("record", { start: !state.status.properties.Recording }); await refresh(); } catch (e) { showError("files_error", e); }
};
$("calibrate").onclick = async () => {
  showError("cal_error", null);
  const frames = Number($("cal_frames").value);
  // sdid's own count of the job's frames (its Job property).
  const timer = setInterval(async () => {
    let s;
    try { s = await api("status"); } catch (e) { return; }
    const job = s.properties.Job || {};
    if (job.frames_total > 0) $("cal_progress").value = Math.min(0.99, job.frames_done / job.frames_total);
  }, 250);
  $("cal_text").textContent = "calibrating...";
  try {
    const r = await api("calibrate", { frames });
    $("cal_progress").value = 1;
    $("cal_text").textContent = `gain ${r.gain_dn_per_electron.toFixed(4)} DN/e-, read variance ${r.ptc_read_variance_dn2.toFixed(2)} DN²`;
  } catch (e) { $("cal_progress").value = 0; $("cal_text").textContent = ""; showError("cal_error", e); }
  clearInterval(timer);
};

// ---- camera picker (several cameras: sdid --cameras N, several boards) ----
async function listCameras() {
  let r;
  try { r = await api("cameras"); } catch (e) { return; }
  const sel = $("camera");
  sel.hidden = r.cameras.length < 2;
  sel.textContent = "";
  for (const c of r.cameras) {
    const o = document.createElement("option");
    o.value = c.serial;
    o.textContent = `${c.serial} (${c.backend}, ${c.mode})`;
    sel.appendChild(o);
  }
  sel.value = r.current;
  state.camera = r.current;
}
$("camera").onchange = async (ev) => {
  try { await api("camera", { serial: ev.target.value }); } catch (e) { showError("mode_error", e); }
  await listCameras();
  await refresh();
};

connect();
listCameras();
refresh();
setInterval(refresh, 1000);
