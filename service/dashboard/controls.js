// The dashboard's controls: a few stereo settings (PATCH /config with If-Match on the ETag it
// read, the refusal's detail shown as the server gave it) and start/stop of a recording (POST
// /recordings, POST /recordings/{name}/stop). Both change state, so they need the API token:
// `rig serve --demo` prints a URL with one (?token=...), which this page keeps in sessionStorage
// and takes out of the address bar; without one the controls are disabled and say why.
"use strict";

const TOKEN_KEY = "rig-api-token";
const STEREO_FIELDS = {
  disparity_range: "number",
  correlation_window_size: "number",
  uniqueness_ratio: "number",
  median: "number",
  lr_check: "checkbox",
};
const $ = (id) => document.getElementById(id);

let token = null;
let etag = null;
let serverHasToken = null;
let running = null; // the running recording's name

// The token from ?token= (kept for this tab, removed from the address bar and history), or the
// one this tab kept.
function takeToken() {
  const url = new URL(window.location.href);
  const given = url.searchParams.get("token");
  if (given) {
    sessionStorage.setItem(TOKEN_KEY, given);
    url.searchParams.delete("token");
    history.replaceState(history.state, "", url.pathname + url.search + url.hash);
  }
  return sessionStorage.getItem(TOKEN_KEY);
}

function detailText(body, status) {
  const detail = body && body.detail;
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail)) {
    return detail.map((e) => `${(e.loc || []).filter((x) => x !== "body").join(".")}: ${e.msg}`).join("; ");
  }
  return "HTTP " + status;
}

async function send(method, path, body, headers = {}) {
  const r = await fetch(path, {
    method,
    cache: "no-store",
    headers: { "Content-Type": "application/json", Authorization: "Bearer " + token, ...headers },
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  let doc = null;
  try { doc = await r.json(); } catch (err) { doc = null; }
  if (r.status === 401) {
    token = null;
    sessionStorage.removeItem(TOKEN_KEY);
    updateEnabled();
  }
  return { status: r.status, ok: r.ok, doc, etag: r.headers.get("ETag") };
}

// Why the controls are off, or null when they are on.
function disabledReason() {
  if (serverHasToken === false) {
    return "Read-only: this service has no API token, so nothing can change its state (set " +
      "server.api_token or RIG_API_TOKEN; `rig serve --demo` makes one and prints a URL with it).";
  }
  if (serverHasToken && !token) {
    return "Read-only: this page has no API token. Open the URL `rig serve` printed (…/?token=…), " +
      "or paste the token below.";
  }
  return null;
}

function updateEnabled() {
  const why = disabledReason();
  const off = why !== null || serverHasToken === null;
  for (const el of document.querySelectorAll("#controls .needs-token")) el.disabled = off;
  $("auth-note").textContent = why || "";
  $("auth-note").hidden = why === null;
  $("token-form").hidden = !(serverHasToken && !token);
  if (!off) $("rec-stop").disabled = running === null;
}

function showStereo(stereo) {
  for (const [name, kind] of Object.entries(STEREO_FIELDS)) {
    const input = $("ctl-" + name);
    if (kind === "checkbox") input.checked = Boolean(stereo[name]);
    else input.value = String(stereo[name]);
  }
}

async function loadConfig() {
  try {
    const r = await fetch("/config", { cache: "no-store" });
    if (!r.ok) throw new Error("HTTP " + r.status);
    etag = r.headers.get("ETag");
    const config = await r.json();
    serverHasToken = config.server.api_token_set;
    showStereo(config.stereo);
    $("config-revision").textContent = `revision ${config.revision}`;
    updateEnabled();
  } catch (err) {
    setTimeout(loadConfig, 2000);
  }
}

async function applyStereo(event) {
  event.preventDefault();
  const changes = {};
  for (const [name, kind] of Object.entries(STEREO_FIELDS)) {
    const input = $("ctl-" + name);
    changes[name] = kind === "checkbox" ? input.checked : Number(input.value);
  }
  const status = $("config-status");
  status.className = "status";
  status.textContent = "applying…";
  const r = await send("PATCH", "/config", { stereo: changes }, etag ? { "If-Match": etag } : {});
  if (r.ok) {
    etag = r.etag;
    showStereo(r.doc.stereo);
    $("config-revision").textContent = `revision ${r.doc.revision}`;
    status.textContent = `in effect from the next frame (revision ${r.doc.revision})`;
    return;
  }
  status.className = "status refused";
  if (r.status === 412) {
    await loadConfig();
    status.textContent = "the settings changed meanwhile; the form shows them now: apply again";
    return;
  }
  status.textContent = `refused (${r.status}): ${detailText(r.doc, r.status)}`;
}

function defaultName() {
  const t = new Date();
  const pad = (x) => String(x).padStart(2, "0");
  return `rec-${t.getFullYear()}${pad(t.getMonth() + 1)}${pad(t.getDate())}-` +
    `${pad(t.getHours())}${pad(t.getMinutes())}${pad(t.getSeconds())}`;
}

async function startRecording(event) {
  event.preventDefault();
  const input = $("rec-name");
  const name = input.value.trim() || defaultName();
  const status = $("rec-status");
  const r = await send("POST", "/recordings", { name });
  if (r.ok) {
    input.value = "";
    showRecording(r.doc);
  } else {
    status.className = "status refused";
    status.textContent = `not started (${r.status}): ${detailText(r.doc, r.status)}`;
  }
}

async function stopRecording() {
  if (running === null) return;
  const name = running;
  const r = await send("POST", `/recordings/${encodeURIComponent(name)}/stop`);
  const status = $("rec-status");
  if (r.ok) {
    running = null;
    status.className = "status";
    status.textContent = `stopped ${r.doc.name}: ${r.doc.pairs} pairs, ${r.doc.dropped} dropped, in ${r.doc.path}`;
    updateEnabled();
  } else {
    status.className = "status refused";
    status.textContent = `not stopped (${r.status}): ${detailText(r.doc, r.status)}`;
  }
}

// The running recording as /health (or a start) reports it; null when none runs.
export function showRecording(rec) {
  const was = running;
  running = rec && rec.active ? rec.name : null;
  if (running !== null) {
    const status = $("rec-status");
    status.className = "status recording";
    status.textContent = `recording ${rec.name}: ${rec.pairs} pairs, ${rec.dropped} dropped`;
  }
  if (was !== running) updateEnabled();
}

export function initControls() {
  token = takeToken();
  $("stereo-form").addEventListener("submit", applyStereo);
  $("rec-form").addEventListener("submit", startRecording);
  $("rec-stop").addEventListener("click", stopRecording);
  $("token-form").addEventListener("submit", (event) => {
    event.preventDefault();
    const given = $("token-input").value.trim();
    if (!given) return;
    token = given;
    sessionStorage.setItem(TOKEN_KEY, given);
    $("token-input").value = "";
    updateEnabled();
  });
  updateEnabled();
  loadConfig();
}
