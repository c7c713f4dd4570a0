// The reglib page: one POST /v1/match/bundle per click; it answers the match and all its files at once.
"use strict";

const $ = (id) => document.getElementById(id);
const INPUTS = ["image_a", "image_b"];
const BUNDLE = "/v1/match/bundle";
const KEY_STORE = "reglib-api-key";  // sessionStorage: this tab only, gone when it closes
let maxSeed = 2 ** 53;
let urls = [];  // object URLs of the result on screen, revoked when it is replaced

// ---- choosing the images: file inputs, drag and drop, the bundled examples ----

function chosen(name) { return $(name).files[0] || null; }

function setFile(name, file) {
  const list = new DataTransfer();
  list.items.add(file);
  $(name).files = list.files;  // the input shows the file's name, as if it had been picked
  showPreview(name);
}

function showPreview(name) {
  const file = chosen(name);
  const img = $("preview-" + name);
  const note = $("note-" + name);
  if (img.src) URL.revokeObjectURL(img.src);
  img.removeAttribute("src");
  img.hidden = true;
  if (!file) { note.textContent = "or drop an image here"; return; }
  note.textContent = `${file.name} (${(file.size / 1024).toFixed(0)} KiB)`;
  img.onload = () => { img.hidden = false; };
  img.onerror = async () => {  // the browser shows no TIFF or NIfTI, and no text file renamed .png either
    img.hidden = true;
    const format = await VIEWS.sniffImage(file);
    note.textContent += format ? `: ${format}, no preview in this browser (the service can still read it)`
      : ": not an image (its first bytes are none of PNG, JPEG, TIFF, BMP, WebP, NIfTI, MetaImage or NRRD)";
  };
  img.src = URL.createObjectURL(file);
}

for (const name of INPUTS) {
  $(name).addEventListener("change", () => showPreview(name));
  const zone = $("drop-" + name);
  zone.addEventListener("dragover", (e) => { e.preventDefault(); zone.classList.add("dragging"); });
  zone.addEventListener("dragleave", () => zone.classList.remove("dragging"));
  zone.addEventListener("drop", (e) => {
    e.preventDefault();
    zone.classList.remove("dragging");
    const dropped = Array.from((e.dataTransfer && e.dataTransfer.files) || []);
    if (dropped.length >= 2) { setFile("image_a", dropped[0]); setFile("image_b", dropped[1]); } else if (dropped.length === 1) setFile(name, dropped[0]);
  });
}
// a file dropped beside the boxes must not replace the page
window.addEventListener("dragover", (e) => e.preventDefault());
window.addEventListener("drop", (e) => e.preventDefault());

$("examples").addEventListener("click", async () => {
  setStatus("loading the examples...");
  try {
    const pair = await (await fetch("/examples")).json();
    for (const name of INPUTS) {
      const response = await fetch(pair[name]);
      if (!response.ok) throw new Error(`${pair[name]}: ${response.status}`);
      const blob = await response.blob();
      setFile(name, new File([blob], pair[name].split("/").pop(), { type: blob.type }));
    }
    setStatus("examples chosen: press Match");
  } catch (err) {
    setStatus(`the examples could not be loaded (${err.message})`, true);
  }
});

// ---- the options: menus and defaults from the service's OpenAPI document (derived from the library) ----

const LABELS = { sift: "SIFT", shape_context: "Shape context", multimodal: "Multimodal (other sensor)", auto: "Auto",
                 l2e: "L2E", vfc: "VFC" };
// What each reason code means, in words: the library's list, read from the API's schema (fillOptions).
let reasonTexts = {};
const touched = new Set();
for (const id of ["features", "method", "dense", "seed"]) {
  $(id).addEventListener("input", () => touched.add(id));
  $(id).addEventListener("change", () => touched.add(id));
}

async function fillOptions() {
  try {
    const doc = await (await fetch("/openapi.json")).json();
    const props = doc.paths[BUNDLE].post.requestBody.content["multipart/form-data"].schema.properties;
    for (const name of ["features", "method"]) {
      const values = (props[name] || {}).enum;
      if (!values || !values.length || touched.has(name)) continue;
      const select = $(name);
      select.replaceChildren(...values.map((v) => new Option(LABELS[v] || v, v)));
      select.value = values.includes(props[name].default) ? props[name].default : values[0];
    }
    if (props.dense && typeof props.dense.default === "boolean" && !touched.has("dense")) $("dense").checked = props.dense.default;
    if (props.seed && Number.isInteger(props.seed.default) && !touched.has("seed")) $("seed").value = String(props.seed.default);
    if (props.seed && Number.isInteger(props.seed.maximum)) maxSeed = props.seed.maximum;
    const reason = ((doc.components || {}).schemas || {}).MatchResponse?.properties?.reason;
    if (reason && reason["x-reasons"]) reasonTexts = reason["x-reasons"];
  } catch (_) { /* keep the built-in menus and defaults, which are the library's */ }
}
fillOptions();

$("alpha").addEventListener("input", (e) => { $("overlay-b").style.opacity = e.target.value / 100; });
for (const id of ["view-blend", "view-checker"]) $(id).addEventListener("change", showView);

// blend (the two images stacked, b's weight on the slider) or checkerboard (tiles of a and of warped b)
function showView() {
  const checker = $("view-checker").checked && $("checker").width > 0;
  $("overlay").hidden = checker;
  $("checker").hidden = !checker;
  $("alpha-label").hidden = checker;
  $("view-hint").textContent = checker
    ? "Tiles of a and of warped b alternate: where they agree, edges run on straight across the tile borders."
    : "Slide the weight: where the two agree, edges stay put while b fades in.";
}

// A whole number from 0 to maxSeed, as text for the form: "1e3" is 1000; "1.5", "-1" or "abc" are refused.
function parseSeed() {
  const input = $("seed");
  const text = input.value.trim();
  const refuse = (what) => new Error(`The seed must be a whole number from 0 to ${maxSeed}, got ${what}.`);
  if (input.validity.badInput) throw refuse("text that is not a number");
  if (text === "") return "0";
  if (/^[0-9]+$/.test(text)) {
    if (BigInt(text) > BigInt(maxSeed)) throw refuse(`"${text}"`);
    return BigInt(text).toString();
  }
  const value = Number(text);
  if (!Number.isSafeInteger(value) || value < 0 || value > maxSeed) throw refuse(`"${text}"`);
  return String(value);
}

function setStatus(text, isError = false) {
  $("status").textContent = text;
  $("status").className = isError ? "error" : "";
}

// ---- the answer ----

function clearResult() {
  for (const url of urls) URL.revokeObjectURL(url);
  urls = [];
  $("result").hidden = true;
  for (const id of ["n-inliers", "n-matches", "timing", "confidence-summary", "notice-reason", "matches-note"]) $(id).textContent = "";
  $("download-list").replaceChildren();
  $("overlay-a").onerror = null;
  for (const id of ["overlay-a", "overlay-b", "flow", "confidence"]) $(id).removeAttribute("src");
  for (const id of ["matches", "checker"]) {
    $(id).width = 0;
    $(id).height = 0;
  }
  $("notice").hidden = true;
  $("matches-note").hidden = true;
  $("error").hidden = true;
}

function objectUrl(blob) {
  const url = URL.createObjectURL(blob);
  urls.push(url);
  return url;
}

function showError(title, detail, advice) {
  clearResult();
  $("error-title").textContent = title;
  VIEWS.setCoded($("error-detail"), detail);
  $("error-advice").textContent = advice || "";
  $("error").hidden = false;
  setStatus("failed: see the message below", true);
  document.body.dataset.state = "error";
}

// What to do about each kind of refusal (the status codes of CONTRACTS.md).
function adviceFor(status, problem, retryAfter) {
  const wait = retryAfter ? `in ${retryAfter} s` : "shortly";
  const type = (problem && problem.type) || "";
  if (status === 400) return "Choose image files the service can decode (PNG, JPEG, TIFF, BMP or WebP).";
  if (status === 413) return "Use smaller images (fewer pixels or bytes), then press Match again.";
  if (status === 415) return "Use a PNG, JPEG, TIFF, BMP or WebP image.";
  if (status === 422 && type.endsWith("estimation-failed")) return "Try other features or the other estimator, or switch dense refinement off.";
  if (status === 422) return "Correct the field the message names, then press Match again.";
  if (status === 429) return `The service is busy with other requests: press Match again ${wait}.`;
  if (status === 503) return `The service is starting or stopping: press Match again ${wait}.`;
  if (status === 504) return "The match took longer than the service allows: try smaller images or switch dense refinement off.";
  return "Press Match again; if it fails again, report it with the request id above.";
}


function decode(base64, type) {
  const text = atob(base64);
  const bytes = new Uint8Array(text.length);
  for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
  return new Blob([bytes], { type });
}

function addDownload(name, blob) {
  const a = document.createElement("a");
  a.href = objectUrl(blob);
  a.download = name;
  a.textContent = name;
  const item = document.createElement("li");
  item.append(a);
  $("download-list").append(item);
}

function loadImage(url) {
  return new Promise((resolve, reject) => {
    const img = new Image();
    img.onload = () => resolve(img);
    img.onerror = () => reject(new Error("the browser cannot show this image"));
    img.src = url;
  });
}

function drawMatches(imgA, imgB, match) {
  const canvas = $("matches");
  const gap = 10;
  canvas.width = imgA.naturalWidth + gap + imgB.naturalWidth;
  canvas.height = Math.max(imgA.naturalHeight, imgB.naturalHeight);
  const ctx = canvas.getContext("2d");
  ctx.fillStyle = "#fff";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  ctx.drawImage(imgA, 0, 0);
  const dx = imgA.naturalWidth + gap;
  ctx.drawImage(imgB, dx, 0);
  const inlier = new Uint8Array(match.n_matches);
  for (const i of match.inliers) inlier[i] = 1;
  ctx.lineWidth = Math.max(1, canvas.width / 1200);
  for (const pass of [0, 1]) {  // outliers first, inliers on top
    ctx.strokeStyle = pass ? "rgba(26,154,26,0.8)" : "rgba(208,48,48,0.6)";
    ctx.beginPath();
    for (let i = 0; i < match.n_matches; i++) {
      if (inlier[i] !== pass) continue;
      // pixel centres are at integer coordinates: +0.5 puts the line on the pixel's centre
      ctx.moveTo(match.src[i][0] + 0.5, match.src[i][1] + 0.5);
      ctx.lineTo(match.dst[i][0] + 0.5 + dx, match.dst[i][1] + 0.5);
    }
    ctx.stroke();
  }
}

async function showResult(bundle, files, seconds) {
  clearResult();
  const match = bundle.match;
  $("n-inliers").textContent = String(match.n_inliers);
  $("n-matches").textContent = String(match.n_matches);
  // `total` is the whole computation; the other stages are parts of it
  const timings = match.timings_ms || {};
  const server = "total" in timings ? timings.total
    : Object.values(timings).reduce((a, b) => a + b, 0);
  $("timing").textContent = `seed ${match.seed}, computed in ${server.toFixed(0)} ms, answered in ${seconds.toFixed(1)} s`;
  addDownload("match.json", new Blob([JSON.stringify(match, null, 2)], { type: "application/json" }));
  addDownload("transform.json", new Blob([JSON.stringify(match.transform, null, 2)], { type: "application/json" }));
  const blobs = {};
  const types = { ".png": "image/png", ".flo": "application/x-flo" };
  for (const [name, data] of Object.entries(bundle.files)) blobs[name] = decode(data, types[name.slice(name.lastIndexOf("."))]);
  const converged = match.converged === true;
  $("notice").hidden = converged;
  // an answer that is not one is headlined as such: its inlier count is no result to read first
  $("matches-line").hidden = !converged;
  $("unreliable").hidden = converged;
  $("dense-results").hidden = !converged;
  if (converged) {
    for (const name of ["warped.png", "overlay.png", "flow.flo", "flow.png", "confidence.png"]) {
      if (blobs[name]) addDownload(name, blobs[name]);
    }
    $("overlay-b").hidden = false;
    $("overlay-b").src = objectUrl(blobs["warped.png"]);
    $("overlay-a").onerror = () => {  // a format the browser cannot show (TIFF, say): the service's overlay.png
      $("overlay-a").onerror = null;
      $("overlay-b").hidden = true;
      $("overlay-a").src = objectUrl(blobs["overlay.png"]);
    };
    $("overlay-a").src = objectUrl(files.image_a);
    $("overlay-b").style.opacity = $("alpha").value / 100;
    $("flow").src = objectUrl(blobs["flow.png"]);
    const largest = blobs["flow.flo"] ? VIEWS.floMaxMagnitude(await blobs["flow.flo"].arrayBuffer()) : null;
    $("flow-scale").textContent = "colour: the direction a pixel of a moves; white: no motion"
      + (largest === null ? "" : `; full colour: ${largest.toFixed(1)} px`);
    const c = match.confidence;
    $("confidence-block").hidden = !blobs["confidence.png"];
    if (blobs["confidence.png"]) $("confidence").src = objectUrl(blobs["confidence.png"]);
    $("confidence-summary").textContent = c ? `(mean ${c.mean.toFixed(2)}, ${(100 * c.supported_share).toFixed(0)} % supported)` : "";
  } else {
    const why = reasonTexts[match.reason] || match.reason || "the estimate did not converge";
    $("notice-reason").textContent = `The service found no transformation it can vouch for: ${why} `
      + `(${match.n_matches} putative matches, ${match.n_inliers} kept by the estimate, shown below).`;
  }
  $("result").hidden = false;
  try {
    const [imgA, imgB] = await Promise.all([loadImage(objectUrl(files.image_a)), loadImage(objectUrl(files.image_b))]);
    drawMatches(imgA, imgB, match);
  } catch (err) {
    $("matches-note").textContent = `The matches are not drawn: ${err.message} (TIFF, say). The downloads hold them.`;
    $("matches-note").hidden = false;
  }
  if (converged) {
    try {
      const [imgA, warped] = await Promise.all([loadImage(objectUrl(files.image_a)), loadImage($("overlay-b").src)]);
      VIEWS.drawChecker($("checker"), imgA, warped);
    } catch (_) { /* a cannot be shown here (TIFF, say): the blend of overlay.png only */ }
  }
  $("view-checker").disabled = $("checker").width === 0;
  showView();
  document.body.dataset.converged = String(converged);
}

// ---- the API key, when the service asks for one (a 401): kept in this tab's session storage only ----

function storedKey() {
  try { return sessionStorage.getItem(KEY_STORE) || ""; } catch (_) { return ""; }
}

function authHeaders() {
  const key = storedKey();
  return key ? { Authorization: `Bearer ${key}` } : {};
}

function askForKey(problem, sentOne) {
  try { sessionStorage.removeItem(KEY_STORE); } catch (_) { /* storage off: the key is asked every time */ }
  clearResult();
  const said = (problem && problem.detail) || "this service needs an API key";
  VIEWS.setCoded($("key-reason"), sentOne
    ? `The key was refused (${said}). Enter another; the request is then sent again.`
    : `The service answered: ${said}. Enter your key; the request is then sent again.`);
  $("key-box").hidden = false;
  $("api-key").value = "";
  $("api-key").focus();
  setStatus("waiting for an API key", true);
  document.body.dataset.state = "key";
}

$("key-form").addEventListener("submit", (event) => {
  event.preventDefault();
  const key = $("api-key").value.trim();
  if (!/^[\x21-\x7e]+$/.test(key)) {
    $("key-reason").textContent = "An API key is one word of printable ASCII characters (no spaces).";
    return;
  }
  try { sessionStorage.setItem(KEY_STORE, key); } catch (_) {
    $("key-reason").textContent = "This browser keeps no session storage for this page, so the key cannot be kept.";
    return;
  }
  $("key-box").hidden = true;
  $("form").requestSubmit();
});

async function readProblem(response) {
  try { return await response.json(); } catch (_) { return null; }
}

$("form").addEventListener("submit", async (event) => {
  event.preventDefault();
  const files = { image_a: chosen("image_a"), image_b: chosen("image_b") };
  let seed;
  try {
    if (!files.image_a || !files.image_b) throw new Error("Choose image a and image b first, or use the bundled examples.");
    seed = parseSeed();
  } catch (err) {
    showError("Nothing was sent", err.message, "");
    return;
  }
  const form = new FormData();
  for (const name of INPUTS) form.append(name, files[name]);
  form.append("features", $("features").value);
  form.append("method", $("method").value);
  form.append("dense", $("dense").checked ? "true" : "false");
  form.append("seed", seed);
  form.append("alpha", String($("alpha").value / 100));

  clearResult();  // the screen shows this request only: its progress, then its answer or its error
  $("run").disabled = true;
  $("progress").hidden = false;
  document.body.dataset.state = "running";
  const start = performance.now();
  const elapsed = () => (performance.now() - start) / 1000;
  const tick = () => setStatus(`matching... ${elapsed().toFixed(1)} s`);
  tick();
  const timer = setInterval(tick, 100);
  try {
    let response;
    try {
      response = await fetch(BUNDLE, { method: "POST", body: form, headers: authHeaders() });
    } catch (err) {
      showError("The service cannot be reached", err.message, "Check that the service is running, then press Match again.");
      return;
    }
    if (response.status === 401) {
      askForKey(await readProblem(response), Boolean(storedKey()));
      return;
    }
    if (!response.ok) {
      const problem = await readProblem(response);
      const id = response.headers.get("X-Request-ID");
      const title = `${response.status}: ${(problem && problem.title) || response.statusText}`;
      const detail = ((problem && problem.detail) || "") + (id ? ` (request id ${id})` : "");
      showError(title, detail, adviceFor(response.status, problem, response.headers.get("Retry-After")));
      return;
    }
    const bundle = await response.json();
    await showResult(bundle, files, elapsed());
    setStatus(`done in ${elapsed().toFixed(1)} s`);
    document.body.dataset.state = "done";
  } catch (err) {
    showError("The answer cannot be shown", err.message, "Press Match again; if it fails again, report it.");
  } finally {
    clearInterval(timer);
    $("progress").hidden = true;
    $("run").disabled = false;
  }
});
