// Metres on the dashboard: the colour bar of the colour depth (GET /depth/colorbar: the server's
// own colour scale, the one /depth/colorized and `rig process --preview` use) and the read-out of
// range and confidence under the pointer (GET /depth/at: a few values per request, whatever the
// image size; one request in flight, the pointer's latest pixel asked next).
"use strict";

const $ = (id) => document.getElementById(id);
let pointer = null; // {img, u, v} of the latest pointer position over an image of the pair grid
let inFlight = false;
let asked = null; // the "u,v,seq" last asked for

function fmtMetres(m) {
  return m === null ? "–" : (m < 10 ? m.toFixed(3) : m.toFixed(2)) + " m";
}

export async function loadColorbar() {
  try {
    const r = await fetch("/depth/colorbar", { cache: "no-store" });
    if (!r.ok) throw new Error("HTTP " + r.status);
    showColorbar(await r.json());
  } catch (err) {
    setTimeout(loadColorbar, 2000);
  }
}

function showColorbar(scale) {
  const bar = $("colorbar");
  const step = Math.max(1, Math.floor(scale.palette.length / 64));
  const stops = [];
  for (let i = 0; i < scale.palette.length; i += step) {
    stops.push(`${scale.palette[i]} ${((100 * i) / (scale.palette.length - 1)).toFixed(2)}%`);
  }
  stops.push(`${scale.palette[scale.palette.length - 1]} 100%`);
  bar.style.background = `linear-gradient(to bottom, ${stops.join(", ")})`;
  const ticks = $("colorbar-ticks");
  ticks.replaceChildren(...scale.ticks.map((t) => {
    const label = document.createElement("span");
    label.className = "tick";
    label.textContent = t.label;
    label.style.top = (100 * t.position).toFixed(2) + "%";
    return label;
  }));
  bar.title = `${scale.scale} scale: ${scale.ticks[0].label} and nearer at the top, ` +
    `${scale.ticks[scale.ticks.length - 1].label} and farther at the bottom; black = no depth`;
  $("depth-scale").textContent = `colour: ${scale.scale} scale from ${scale.ticks[0].label} (dark red) ` +
    `to ${scale.ticks[scale.ticks.length - 1].label} (dark blue), black = no depth`;
}

function pixelOf(img, event) {
  const rect = img.getBoundingClientRect();
  if (!img.naturalWidth || rect.width === 0 || rect.height === 0) return null;
  const u = Math.floor(((event.clientX - rect.left) / rect.width) * img.naturalWidth);
  const v = Math.floor(((event.clientY - rect.top) / rect.height) * img.naturalHeight);
  if (u < 0 || v < 0 || u >= img.naturalWidth || v >= img.naturalHeight) return null;
  return { u, v };
}

async function ask() {
  if (inFlight || pointer === null) return;
  const { u, v } = pointer;
  const key = `${u},${v},${pointer.seq}`;
  if (key === asked) return;
  inFlight = true;
  asked = key;
  try {
    const r = await fetch(`/depth/at?u=${u}&v=${v}`, { cache: "no-store" });
    const body = await r.json();
    if (!r.ok) throw new Error(typeof body.detail === "string" ? body.detail : "HTTP " + r.status);
    showReadout(body);
  } catch (err) {
    $("readout").textContent = `(${u}, ${v}): ${err.message}`;
  } finally {
    inFlight = false;
    if (pointer !== null && `${pointer.u},${pointer.v},${pointer.seq}` !== asked) ask();
  }
}

function showReadout(p) {
  const out = $("readout");
  out.dataset.range = p.range_m === null ? "" : String(p.range_m);
  if (p.range_m === null) {
    out.textContent = `(${p.u}, ${p.v}): no depth here (frame ${p.seq})`;
    return;
  }
  const depth = p.depth_m !== null && p.depth_m !== p.range_m ? `, depth z ${fmtMetres(p.depth_m)}` : "";
  const conf = p.confidence === null ? "" : `, confidence ${p.confidence.toFixed(2)}`;
  const disp = p.disparity_px === null ? "" : `, disparity ${p.disparity_px.toFixed(2)} px`;
  out.textContent = `(${p.u}, ${p.v}): range ${fmtMetres(p.range_m)}${depth}${conf}${disp} (frame ${p.seq})`;
}

let currentSeq = null;

// A new depth frame: the value under a still pointer is asked again.
export function onDepthFrame(seq) {
  currentSeq = seq;
  if (pointer !== null) {
    pointer.seq = seq;
    ask();
  }
}

export function initReadout(imageIds) {
  for (const id of imageIds) {
    const img = $(id);
    img.addEventListener("mousemove", (event) => {
      const px = pixelOf(img, event);
      if (px === null) return;
      pointer = { ...px, seq: currentSeq };
      ask();
    });
    img.addEventListener("mouseleave", () => { pointer = null; });
  }
}
