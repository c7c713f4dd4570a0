// The reglib page: sends the two images to /v1/match, /v1/warp and /v1/flow and shows the answers.
"use strict";

const $ = (id) => document.getElementById(id);
let files = { image_a: null, image_b: null };

for (const name of ["image_a", "image_b"]) {
  $(name).addEventListener("change", (e) => { files[name] = e.target.files[0] || null; });
}

$("examples").addEventListener("click", async () => {
  setStatus("loading the examples...");
  for (const [name, url] of [["image_a", "/static/example_a.jpg"], ["image_b", "/static/example_b.jpg"]]) {
    const blob = await (await fetch(url)).blob();
    files[name] = new File([blob], url.split("/").pop(), { type: blob.type });
  }
  setStatus("examples loaded");
});

// The feature and estimator menus list what the service accepts: the enums of its OpenAPI schema,
// which the service derives from the library (a new feature kind appears here with no edit).
const LABELS = { sift: "SIFT", shape_context: "Shape context", multimodal: "Multimodal (other sensor)", auto: "Auto",
                 l2e: "L2E", vfc: "VFC" };
async function fillMenus() {
  try {
    const doc = await (await fetch("/openapi.json")).json();
    const props = doc.paths["/v1/match"].post.requestBody.content["multipart/form-data"].schema.properties;
    for (const name of ["features", "method"]) {
      const values = (props[name] || {}).enum;
      if (!values || !values.length) continue;
      const select = $(name);
      const current = select.value;
      select.replaceChildren(...values.map((v) => new Option(LABELS[v] || v, v)));
      select.value = values.includes(current) ? current : values[0];
    }
  } catch (_) { /* keep the built-in menus */ }
}
fillMenus();

$("alpha").addEventListener("input", (e) => { $("overlay-b").style.opacity = e.target.value / 100; });

function setStatus(text, isError = false) {
  $("status").textContent = text;
  $("status").className = isError ? "error" : "";
}

function formData(extra) {
  const fd = new FormData();
  fd.append("image_a", files.image_a);
  fd.append("image_b", files.image_b);
  fd.append("features", $("features").value);
  fd.append("method", $("method").value);
  fd.append("dense", $("dense").checked ? "true" : "false");
  fd.append("seed", String(parseInt($("seed").value || "0", 10)));
  for (const [k, v] of Object.entries(extra || {})) fd.append(k, v);
  return fd;
}

async function post(path, extra) {
  const response = await fetch(path, { method: "POST", body: formData(extra) });
  if (!response.ok) {
    let detail = response.statusText;
    try { const p = await response.json(); detail = p.title + ": " + p.detail; } catch (_) { /* not JSON */ }
    throw new Error(`${path}: ${response.status} ${detail}`);
  }
  return response;
}

function loadImage(blob) {
  return new Promise((resolve, reject) => {
    const img = new Image();
    img.onload = () => resolve(img);
    img.onerror = () => reject(new Error("the browser cannot show this image"));
    img.src = URL.createObjectURL(blob);
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
  ctx.lineWidth = 1;
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

$("form").addEventListener("submit", async (event) => {
  event.preventDefault();
  if (!files.image_a || !files.image_b) { setStatus("pick two images, or use the examples", true); return; }
  $("run").disabled = true;
  setStatus("matching...");
  try {
    const match = await (await post("/v1/match")).json();
    const [imgA, imgB] = await Promise.all([loadImage(files.image_a), loadImage(files.image_b)]);
    drawMatches(imgA, imgB, match);
    $("n-inliers").textContent = String(match.n_inliers);
    $("n-matches").textContent = String(match.n_matches);
    const total = Object.values(match.timings_ms || {}).reduce((a, b) => a + b, 0);
    $("timing").textContent = `seed ${match.seed}, ${total.toFixed(0)} ms` + (match.reason ? `, ${match.reason}` : "");
    $("result").hidden = false;
    setStatus("warping...");
    const c = match.confidence;
    $("confidence-summary").textContent = c ? `(mean ${c.mean.toFixed(2)}, ${(100 * c.supported_share).toFixed(0)} % supported)` : "";
    const wantConfidence = c !== null && c !== undefined;
    const [warp, flow, conf] = await Promise.all([post("/v1/warp"), post("/v1/flow", { format: "png" }),
      wantConfidence ? post("/v1/confidence", { format: "png" }) : Promise.resolve(null)]);
    $("confidence").hidden = !conf;
    if (conf) $("confidence").src = URL.createObjectURL(await conf.blob());
    $("overlay-a").src = URL.createObjectURL(files.image_a);
    $("overlay-b").src = URL.createObjectURL(await warp.blob());
    $("overlay-b").style.opacity = $("alpha").value / 100;
    $("flow").src = URL.createObjectURL(await flow.blob());
    setStatus("done");
    document.body.dataset.state = "done";
  } catch (err) {
    setStatus(err.message, true);
    document.body.dataset.state = "error";
  } finally {
    $("run").disabled = false;
  }
});
