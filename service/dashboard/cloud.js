// The point cloud view: GET /pointcloud (binary PLY, rig frame: x right, y down, z forward, metres,
// coloured from the left rectified view) drawn on a 2D canvas with a z-buffer, no library and no
// GPU. Drag turns the view about the cloud's centre, the wheel zooms. A new cloud is fetched at
// most every REFRESH_MS while the view is on screen, one request at a time.
"use strict";

const REFRESH_MS = 1000;
const STRIDE = 4;
const $ = (id) => document.getElementById(id);

let cloud = null; // {xyz: Float32Array, rgb: Uint8Array, n, centre: [x, y, z], radius}
let view = { yaw: 0.0, pitch: -0.35, zoom: 1.0 };
let loading = false;
let lastFetch = 0;
let pendingSeq = null;
let drawQueued = false;

const TYPES = {
  float: [4, "getFloat32"], float32: [4, "getFloat32"], double: [8, "getFloat64"],
  uchar: [1, "getUint8"], uint8: [1, "getUint8"],
};

// Binary little-endian PLY with x y z (+ red green blue): the points and their colours.
export function parsePly(buffer) {
  const bytes = new Uint8Array(buffer);
  const marker = "end_header\n";
  let end = -1;
  for (let i = 0; i < Math.min(bytes.length, 4096) - marker.length; i++) {
    if (bytes[i] === 101 && String.fromCharCode(...bytes.subarray(i, i + marker.length)) === marker) {
      end = i + marker.length;
      break;
    }
  }
  if (end < 0) throw new Error("not a PLY file");
  const header = new TextDecoder().decode(bytes.subarray(0, end)).split("\n");
  if (!header.includes("format binary_little_endian 1.0")) throw new Error("not binary little-endian PLY");
  let n = 0;
  const props = [];
  let stride = 0;
  for (const line of header) {
    const parts = line.trim().split(/\s+/);
    if (parts[0] === "element" && parts[1] === "vertex") n = Number(parts[2]);
    if (parts[0] === "property" && parts.length === 3) {
      const [size, getter] = TYPES[parts[1]] || [];
      if (!size) throw new Error("PLY property type " + parts[1]);
      props.push({ name: parts[2], offset: stride, getter });
      stride += size;
    }
  }
  const at = Object.fromEntries(props.map((p) => [p.name, p]));
  const data = new DataView(buffer, end);
  const xyz = new Float32Array(3 * n);
  const rgb = new Uint8Array(3 * n).fill(220);
  const colour = at.red && at.green && at.blue;
  for (let i = 0; i < n; i++) {
    const base = i * stride;
    xyz[3 * i] = data[at.x.getter](base + at.x.offset, true);
    xyz[3 * i + 1] = data[at.y.getter](base + at.y.offset, true);
    xyz[3 * i + 2] = data[at.z.getter](base + at.z.offset, true);
    if (colour) {
      rgb[3 * i] = data.getUint8(base + at.red.offset);
      rgb[3 * i + 1] = data.getUint8(base + at.green.offset);
      rgb[3 * i + 2] = data.getUint8(base + at.blue.offset);
    }
  }
  return { xyz, rgb, n };
}

// The cloud's centre (median of each axis) and the radius holding most of it.
function frame(pc) {
  const centre = [0, 1, 2].map((k) => {
    const values = new Float32Array(pc.n);
    for (let i = 0; i < pc.n; i++) values[i] = pc.xyz[3 * i + k];
    values.sort();
    return pc.n ? values[pc.n >> 1] : 0;
  });
  const dist = new Float32Array(pc.n);
  for (let i = 0; i < pc.n; i++) {
    const dx = pc.xyz[3 * i] - centre[0], dy = pc.xyz[3 * i + 1] - centre[1], dz = pc.xyz[3 * i + 2] - centre[2];
    dist[i] = Math.hypot(dx, dy, dz);
  }
  dist.sort();
  const radius = pc.n ? Math.max(0.1, dist[Math.floor(0.9 * (pc.n - 1))]) : 1;
  return { ...pc, centre, radius };
}

function draw() {
  drawQueued = false;
  const canvas = $("cloud");
  const ctx = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height;
  const image = ctx.createImageData(w, h);
  const px = image.data;
  for (let i = 3; i < px.length; i += 4) px[i] = 255; // opaque black
  if (cloud === null || cloud.n === 0) {
    ctx.putImageData(image, 0, 0);
    return 0;
  }
  const zbuf = new Float32Array(w * h).fill(Infinity);
  const cy = Math.cos(view.yaw), sy = Math.sin(view.yaw);
  const cp = Math.cos(view.pitch), sp = Math.sin(view.pitch);
  const distance = (1.5 * cloud.radius) / view.zoom;
  const f = 0.9 * Math.min(w, h);
  const [ox, oy, oz] = cloud.centre;
  let drawn = 0;
  for (let i = 0; i < cloud.n; i++) {
    const x0 = cloud.xyz[3 * i] - ox, y0 = cloud.xyz[3 * i + 1] - oy, z0 = cloud.xyz[3 * i + 2] - oz;
    const x1 = cy * x0 - sy * z0, z1 = sy * x0 + cy * z0; // turn about the vertical (y, down)
    const y2 = cp * y0 - sp * z1, z2 = sp * y0 + cp * z1 + distance; // then about x
    if (z2 < 0.05) continue;
    const u = Math.round(w / 2 + (f * x1) / z2), v = Math.round(h / 2 + (f * y2) / z2);
    if (u < 0 || v < 0 || u >= w - 1 || v >= h - 1) continue;
    let hit = false;
    for (const k of [v * w + u, v * w + u + 1, (v + 1) * w + u, (v + 1) * w + u + 1]) {
      if (z2 >= zbuf[k]) continue;
      zbuf[k] = z2;
      px[4 * k] = cloud.rgb[3 * i];
      px[4 * k + 1] = cloud.rgb[3 * i + 1];
      px[4 * k + 2] = cloud.rgb[3 * i + 2];
      hit = true;
    }
    if (hit) drawn++;
  }
  ctx.putImageData(image, 0, 0);
  canvas.dataset.drawn = String(drawn);
  return drawn;
}

function queueDraw() {
  if (drawQueued) return;
  drawQueued = true;
  requestAnimationFrame(draw);
}

async function fetchCloud(seq) {
  loading = true;
  lastFetch = performance.now();
  try {
    const r = await fetch(`/pointcloud?stride=${STRIDE}&seq=${seq}`, { cache: "no-store" });
    if (!r.ok) throw new Error("HTTP " + r.status);
    cloud = frame(parsePly(await r.arrayBuffer()));
    $("cloud-caption").textContent =
      `point cloud, rig frame (x right, y down, z ahead): ${cloud.n} points of frame ${seq}, ` +
      `every ${STRIDE}th pixel; drag to turn, wheel to zoom`;
    queueDraw();
  } catch (err) {
    $("cloud-caption").textContent = "point cloud: " + err.message;
  } finally {
    loading = false;
  }
}

function visible(el) {
  const r = el.getBoundingClientRect();
  return r.bottom > 0 && r.top < window.innerHeight && r.width > 0;
}

// A new depth frame: fetch its cloud if the view is on screen and the last one is old enough.
export function onCloudFrame(seq) {
  pendingSeq = seq;
  if (loading || performance.now() - lastFetch < REFRESH_MS || !visible($("cloud"))) return;
  fetchCloud(seq);
}

export function initCloud() {
  const canvas = $("cloud");
  let drag = null;
  canvas.addEventListener("pointerdown", (e) => {
    drag = { x: e.clientX, y: e.clientY };
    canvas.setPointerCapture(e.pointerId);
  });
  canvas.addEventListener("pointermove", (e) => {
    if (drag === null) return;
    view.yaw += (e.clientX - drag.x) * 0.01;
    view.pitch = Math.max(-1.5, Math.min(1.5, view.pitch - (e.clientY - drag.y) * 0.01));
    drag = { x: e.clientX, y: e.clientY };
    queueDraw();
  });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    view.zoom = Math.max(0.2, Math.min(20, view.zoom * Math.exp(-e.deltaY * 0.001)));
    queueDraw();
  }, { passive: false });
  // A view scrolled into sight fetches the newest frame's cloud at once.
  setInterval(() => {
    if (pendingSeq !== null && cloud === null && !loading && visible(canvas)) fetchCloud(pendingSeq);
  }, REFRESH_MS);
  draw();
}
