// The page's views of an answer beside the blend: a checkerboard of a and warped b, the flow's scale from
// flow.flo, backticked names shown as code, and what a chosen file's first bytes say it is.
"use strict";

const VIEWS = {
  // a's tiles and warped b's tiles alternate: at a tile edge, a structure that continues straight is aligned
  drawChecker(canvas, imgA, imgB) {
    const w = imgA.naturalWidth, h = imgA.naturalHeight;
    canvas.width = w;
    canvas.height = h;
    const ctx = canvas.getContext("2d");
    ctx.drawImage(imgA, 0, 0);
    const tile = Math.max(16, Math.round(Math.max(w, h) / 8));
    for (let row = 0; row * tile < h; row++) {
      for (let col = (row + 1) % 2; col * tile < w; col += 2) {
        const x = col * tile, y = row * tile, tw = Math.min(tile, w - x), th = Math.min(tile, h - y);
        ctx.drawImage(imgB, x, y, tw, th, x, y, tw, th);  // b is in a's frame: the same pixels
      }
    }
    return tile;
  },

  // the largest |(dx, dy)| of a Middlebury .flo ("PIEH", width, height, then float32 pairs): flow.png's
  // full colour stands for it (reglib.visualize.flow_to_color scales by the largest magnitude)
  floMaxMagnitude(buffer) {
    const view = new DataView(buffer);
    if (buffer.byteLength < 12 || Math.abs(view.getFloat32(0, true) - 202021.25) > 1) return null;
    const n = view.getInt32(4, true) * view.getInt32(8, true);
    if (buffer.byteLength < 12 + 8 * n) return null;
    const values = new Float32Array(buffer, 12, 2 * n);
    let largest = 0;
    for (let i = 0; i < values.length; i += 2) {
      const m = Math.hypot(values[i], values[i + 1]);
      if (m > largest) largest = m;
    }
    return largest;
  },

  // text with `names` shown as code, built as nodes (never as HTML from the answer)
  setCoded(element, text) {
    const parts = String(text || "").split("`");
    const nodes = parts.map((part, i) => {
      if (i % 2 === 0 || i === parts.length - 1) return document.createTextNode(i % 2 === 0 ? part : "`" + part);
      const code = document.createElement("code");
      code.textContent = part;
      return code;
    });
    element.replaceChildren(...nodes);
  },

  // the format the first bytes of a file name, or null: what the service reads (README, "Input images")
  async sniffImage(file) {
    const b = new Uint8Array(await file.slice(0, 352).arrayBuffer());
    const at = (offset, text) => Array.from(text).every((c, i) => b[offset + i] === c.charCodeAt(0));
    if (b[0] === 0x89 && at(1, "PNG")) return "PNG";
    if (b[0] === 0xff && b[1] === 0xd8) return "JPEG";
    if (at(0, "II*\0") || at(0, "MM\0*")) return "TIFF";
    if (at(0, "BM")) return "BMP";
    if (at(0, "RIFF") && at(8, "WEBP")) return "WebP";
    if (b[0] === 0x1f && b[1] === 0x8b) return "gzip (a .nii.gz, say)";
    if (at(344, "n+1\0") || at(344, "ni1\0")) return "NIfTI";
    if (at(0, "NRRD")) return "NRRD";
    if (at(0, "ObjectType") || at(0, "NDims")) return "MetaImage";
    return null;
  },
};
