// Dashboard: polls /health, refreshes the images when a new depth frame is out, and outlines the
// VPC footprint (from /calibration) on the fisheye frames. Plain JS, no build step.
"use strict";

const HEALTH_PERIOD_MS = 400;
const IMAGE_IDS = ["depth-img", "confidence-img", "vpc-left", "vpc-right", "raw-left", "raw-right"];
const CAMERAS = ["left", "right"];
let lastSeq = null;
let calibration = null;

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

for (const id of IMAGE_IDS) {
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

async function loadCalibration() {
  try {
    const r = await fetch("/calibration", { cache: "no-store" });
    if (!r.ok) throw new Error("HTTP " + r.status);
    calibration = await r.json();
    const v = calibration.vpc;
    $("vpc-info").textContent =
      `VPC ${v.width}×${v.height}, fx ${v.fx.toFixed(1)} px, baseline ${(calibration.baseline_m * 1000).toFixed(1)} mm`;
    CAMERAS.forEach(drawFootprint);
  } catch (err) {
    setTimeout(loadCalibration, 2000);
  }
}

function showHealth(h) {
  const status = $("status");
  status.textContent = h.status;
  status.className = "badge " + h.status;
  $("fps").textContent = fmt(h.worker.fps, 1);
  $("latency").textContent = fmt(h.worker.latency_ms, 0);
  $("seq").textContent = h.worker.last_seq === null ? "–" : h.worker.last_seq;
  $("worker-fps").textContent = fmt(h.worker.fps, 1);
  $("worker-latency").textContent = fmt(h.worker.latency_ms, 1);
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
  for (const name of CAMERAS) {
    const cam = h.cameras[name];
    if (!cam) continue;
    const state = $(`cam-${name}-state`);
    state.textContent = cam.state;
    state.className = cam.state;
    $(`cam-${name}-reason`).textContent = cam.connected ? "" : (cam.reason || cam.last_error || "");
    $(`cam-${name}-fps`).textContent = fmt(cam.fps, 1);
    $(`cam-${name}-dropped`).textContent = cam.frames_dropped;
    $(`cam-${name}-broken`).textContent = cam.frames_corrupt + cam.frames_undecodable;
    $(`cam-${name}-age`).textContent =
      cam.last_frame_age_ms === null ? "–" : fmt(cam.last_frame_age_ms, 0) + " ms ago";
    $(`banner-${name}`).hidden = cam.connected;
  }
  const seq = h.worker.last_seq;
  if (seq !== null && seq !== lastSeq) {
    lastSeq = seq;
    for (const id of IMAGE_IDS) refreshImage($(id), seq);
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

loadCalibration();
pollHealth();
