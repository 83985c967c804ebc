// Dashboard: polls /health, refreshes the images when a new depth frame is out, and outlines the
// rectified pair's footprint (from /calibration) on the fisheye frames. The camera table's figure
// columns come from the counter table (/counters): each camera counter with a `column` is shown
// there, those sharing a column summed. The colour bar and the read-out under the pointer are
// readout.js's, the point cloud cloud.js's, the stereo and recording controls controls.js's.
// Plain JS modules, no build step.
"use strict";

import { initCloud, onCloudFrame } from "/dashboard/cloud.js";
import { initControls, showRecording } from "/dashboard/controls.js";
import { initReadout, loadColorbar, onDepthFrame } from "/dashboard/readout.js";

const HEALTH_PERIOD_MS = 400;
const IMAGE_IDS = ["depth-img", "confidence-img", "vpc-left", "vpc-right", "raw-left", "raw-right"];
// The shown pair's two sides (their views, fisheye frames and overlays); the camera table lists
// every camera /health does.
const SIDES = ["left", "right"];
let lastSeq = null;
let calibration = null;
let columns = null; // [{id, label, names, digits}] from /counters

const $ = (id) => document.getElementById(id);

function fmt(value, digits) {
  return value === null || value === undefined ? "–" : Number(value).toFixed(digits);
}

function bytes(n) {
  if (n === null || n === undefined) return "–";
  const units = ["B", "KB", "MB", "GB", "TB"];
  let i = 0;
  while (n >= 1024 && i < units.length - 1) { n /= 1024; i++; }
  return n.toFixed(1) + " " + units[i];
}

// One request in flight per image: a slow network skips frames instead of queueing them.
function refreshImage(img, seq) {
  if (img.dataset.loading === "1") return;
  img.dataset.loading = "1";
  const base = img.dataset.src;
  img.src = base + (base.includes("?") ? "&" : "?") + "seq=" + seq;
}

for (const id of [...IMAGE_IDS, "panorama-img"]) {
  const img = $(id);
  img.addEventListener("load", () => { img.dataset.loading = "0"; });
  img.addEventListener("error", () => { img.dataset.loading = "0"; });
}

function drawFootprint(camera) {
  if (!calibration) return;
  const cam = calibration.cameras[camera];
  const canvas = $("overlay-" + camera);
  if (!cam || !canvas) return;
  canvas.width = cam.width;
  canvas.height = cam.height;
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const pts = cam.footprint;
  if (!pts.length) return;
  ctx.strokeStyle = "#00e5ff";
  ctx.lineWidth = Math.max(2, cam.width / 320);
  ctx.beginPath();
  ctx.moveTo(pts[0][0], pts[0][1]);
  for (const [u, v] of pts.slice(1)) ctx.lineTo(u, v);
  ctx.closePath();
  ctx.stroke();
}

// The camera table's columns: camera counters with a `column`, in table order, one per label.
function cameraColumns(counters) {
  const byLabel = new Map();
  for (const c of counters) {
    if (c.group !== "camera" || !c.column) continue;
    if (!byLabel.has(c.column)) {
      const id = c.column.toLowerCase().replace(/[^a-z0-9]+/g, "-").replace(/^-|-$/g, "");
      byLabel.set(c.column, { id, label: c.column, names: [], help: [], digits: c.digits });
    }
    const col = byLabel.get(c.column);
    col.names.push(c.name);
    col.help.push(`${c.name}: ${c.help} (${c.unit})`);
  }
  return [...byLabel.values()];
}

function buildColumns(cols) {
  const head = $("health-head");
  for (const col of cols) {
    const th = document.createElement("th");
    th.textContent = col.label;
    th.id = "col-" + col.id;
    th.title = (col.names.length > 1 ? col.names.join(" + ") + "\n" : "") + col.help.join("\n");
    head.appendChild(th);
  }
  columns = cols;
  for (const row of $("health-body").rows) addColumnCells(row, row.dataset.camera);
}

function addCell(row, id, text) {
  const td = document.createElement("td");
  td.id = id;
  td.textContent = text;
  row.appendChild(td);
}

function addColumnCells(row, name) {
  for (const col of columns || []) addCell(row, `cam-${name}-${col.id}`, "–");
}

// A row for every camera /health lists that has none yet (in its order), with the columns known.
function ensureCameraRows(names) {
  for (const name of names) {
    if ($(`cam-${name}-row`)) continue;
    const row = document.createElement("tr");
    row.id = `cam-${name}-row`;
    row.dataset.camera = name;
    for (const [suffix, text] of [["name", name], ["state", "–"], ["reason", ""]]) {
      addCell(row, `cam-${name}-${suffix}`, text);
    }
    addColumnCells(row, name);
    $("health-body").appendChild(row);
  }
}

async function loadCounters() {
  try {
    const r = await fetch("/counters", { cache: "no-store" });
    if (!r.ok) throw new Error("HTTP " + r.status);
    buildColumns(cameraColumns(await r.json()));
  } catch (err) {
    setTimeout(loadCounters, 2000);
  }
}

// A column's value: its counters summed; "–" while any of them is null.
function columnText(cam, col) {
  let sum = 0;
  for (const name of col.names) {
    const v = cam[name];
    if (v === null || v === undefined) return "–";
    sum += Number(v);
  }
  return sum.toFixed(col.digits);
}

// What the pair in effect is, in the header and the captions (its projection and real size).
function showPair(v, baselineM) {
  const baseline = `baseline ${(baselineM * 1000).toFixed(1)} mm`;
  const latlon = v.projection === "latlon";
  const kind = latlon ? "lat-lon" : "pinhole";
  if (latlon) {
    // The wide pair: a tall image over the whole overlap, range rather than depth.
    document.body.classList.add("wide");
    document.body.style.setProperty("--pair-aspect", String(v.width / v.height));
    $("pair-info").textContent =
      `lat-lon pair ${v.width}×${v.height}, ${v.px_per_deg.toFixed(2)} px/deg, ${baseline}`;
    $("depth-what").textContent = "range along each ray (left lat-lon view)";
  } else {
    $("pair-info").textContent = `pinhole pair ${v.width}×${v.height}, ${v.hfov_deg.toFixed(0)}° wide, ` +
      `fx ${v.fx.toFixed(1)} px, ${baseline}`;
    $("depth-what").textContent = "depth z (left pinhole view)";
  }
  for (const side of SIDES) {
    $(`vpc-${side}-caption`).textContent = `${side} ${kind} view`;
    $(`footprint-${side}-caption`).textContent =
      latlon ? `${side} fisheye, the overlap outlined` : `${side} fisheye, the pinhole view outlined`;
  }
}

async function loadCalibration() {
  try {
    const r = await fetch("/calibration", { cache: "no-store" });
    if (!r.ok) throw new Error("HTTP " + r.status);
    calibration = await r.json();
    showPair(calibration.vpc, calibration.baseline_m);
    SIDES.forEach(drawFootprint);
  } catch (err) {
    setTimeout(loadCalibration, 2000);
  }
}

function showHealth(h) {
  const status = $("status");
  status.textContent = h.status;
  status.className = "badge " + h.status;
  $("fps").textContent = fmt(h.worker.fps, 1);
  $("latency").textContent = fmt(h.worker.processing_ms, 0);
  $("seq").textContent = h.worker.last_seq === null ? "–" : h.worker.last_seq;
  $("worker-fps").textContent = fmt(h.worker.fps, 1);
  $("worker-latency").textContent = fmt(h.worker.processing_ms, 1);
  $("skew").textContent = fmt(h.pairing.skew_ms, 2);
  $("host-temp").textContent = h.host.cpu_temp_c === null ? "n/a" : h.host.cpu_temp_c.toFixed(0) + " °C";
  $("host-load").textContent = h.host.load_avg ? h.host.load_avg.map((x) => x.toFixed(2)).join(" ") : "n/a";
  $("host-disk").textContent = bytes(h.host.disk_free_bytes);
  const reasons = $("reasons");
  reasons.replaceChildren(...h.reasons.map((text) => {
    const li = document.createElement("li");
    li.textContent = text;
    return li;
  }));
  ensureCameraRows(Object.keys(h.cameras));
  for (const [name, cam] of Object.entries(h.cameras)) {
    const state = $(`cam-${name}-state`);
    state.textContent = cam.state;
    state.className = cam.state;
    $(`cam-${name}-reason`).textContent = cam.connected
      ? (cam.degraded_reason || "")
      : (cam.reason || cam.last_error || "");
    for (const col of columns || []) $(`cam-${name}-${col.id}`).textContent = columnText(cam, col);
    const banner = $(`banner-${name}`); // on the fisheye frames shown: left and right
    if (banner) banner.hidden = cam.connected;
  }
  showRecording(h.recording);
  const seq = h.worker.last_seq;
  if (seq !== null && seq !== lastSeq) {
    lastSeq = seq;
    for (const id of IMAGE_IDS) refreshImage($(id), seq);
    // A rig of N cameras (health lists its pairs): its panorama too.
    $("panorama-row").hidden = !h.pairs;
    if (h.pairs) refreshImage($("panorama-img"), seq);
    onDepthFrame(seq);
    onCloudFrame(seq);
  }
}

async function pollHealth() {
  try {
    const r = await fetch("/health", { cache: "no-store" });
    showHealth(await r.json());
  } catch (err) {
    const status = $("status");
    status.textContent = "unreachable";
    status.className = "badge unreachable";
  } finally {
    setTimeout(pollHealth, HEALTH_PERIOD_MS);
  }
}

loadCounters();
loadCalibration();
loadColorbar();
initReadout(["depth-img", "confidence-img"]);
initCloud();
initControls();
pollHealth();
