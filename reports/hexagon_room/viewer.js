// The report page's HDR image viewer: linear float32 RGB images (window.VIEWER_IMAGES, from
// viewer_images.js) shown with an exposure and a display transform, zoomed to single pixels with
// nearest-neighbour display, panned, and read out pixel by pixel. validation/viewer/page.py copies it
// beside each page.
"use strict";
(function () {
  const specElement = document.getElementById("viewer-spec");
  if (!specElement) return;  // a page without images
  const spec = JSON.parse(specElement.textContent);
  const loaded = window.VIEWER_IMAGES;
  if (!Array.isArray(loaded) || loaded.length !== spec.names.length) {
    throw new Error("viewer: viewer_images.js did not load (expected " + spec.names.length + " images)");
  }
  const W = spec.width, H = spec.height, N = W * H;

  // base64 -> inflate -> four byte planes interleaved back into little-endian float32 (page.py writes them)
  async function decode(image) {
    const text = atob(image.data), deflated = new Uint8Array(text.length);
    for (let i = 0; i < text.length; i++) deflated[i] = text.charCodeAt(i);
    const inflated = new Response(new Blob([deflated]).stream().pipeThrough(new DecompressionStream("deflate")));
    const planes = new Uint8Array(await inflated.arrayBuffer()), n = 3 * N;
    if (planes.length !== 4 * n) throw new Error("viewer: " + image.name + " holds " + planes.length + " bytes, not " + 4 * n);
    const bytes = new Uint8Array(4 * n);
    for (let i = 0; i < n; i++) {
      bytes[4 * i] = planes[i]; bytes[4 * i + 1] = planes[n + i];
      bytes[4 * i + 2] = planes[2 * n + i]; bytes[4 * i + 3] = planes[3 * n + i];
    }
    return new Float32Array(bytes.buffer);  // little-endian, as every platform with a browser
  }

  Promise.all(loaded.map(decode)).then(start);  // a failure is an uncaught rejection: the console shows it

  function start(decoded) {
    // ---- the views: the images, their compared pair's difference and relative error, the block test
    const views = loaded.map((im, i) => ({ name: im.name, label: im.name, kind: "image", data: decoded[i],
                                          transform: "srgb", exposure: 0 }));
    if (spec.compare) {
      const [ia, ib] = spec.compare, a = views[ia].data, b = views[ib].data;
      const diff = new Float32Array(3 * N), rel = new Float32Array(3 * N);
      for (let i = 0; i < 3 * N; i++) {
        diff[i] = a[i] - b[i];  // exact in double (operands within 2^29 of each other), rounded once: NumPy's float32
        rel[i] = (a[i] - b[i]) / (Math.abs(b[i]) + spec.epsilon);
      }
      const an = views[ia].name, bn = views[ib].name;
      views.push({ name: an + " \u2212 " + bn, label: "difference", kind: "difference", data: diff,
                   transform: "signed", exposure: autoExposure(diff, false) });
      views.push({ name: "(" + an + " \u2212 " + bn + ") / (|" + bn + "| + " + spec.epsilon + ")", label: "relative error",
                   kind: "relative", data: rel, transform: "magnitude", exposure: autoExposure(rel, true) });
    }
    const blocks = spec.blocks;
    if (blocks) views.push({ name: blocks.label, label: blocks.label, kind: "blocks", data: null, transform: "blocks", exposure: 0 });
    views.forEach((v) => { v.defaultExposure = v.exposure; });

    // Exposure that puts the 99th percentile of the per-pixel channel mean (or mean magnitude) at 1.
    function autoExposure(data, magnitude) {
      const step = Math.max(1, Math.floor(N / 100000)), sample = [];
      for (let p = 0; p < N; p += step) {
        const r = data[3 * p], g = data[3 * p + 1], b = data[3 * p + 2];
        const m = magnitude ? (Math.abs(r) + Math.abs(g) + Math.abs(b)) / 3 : Math.abs(r + g + b) / 3;
        if (Number.isFinite(m)) sample.push(m);
      }
      sample.sort((x, y) => x - y);
      const q = sample.length ? sample[Math.floor(0.99 * (sample.length - 1))] : 0;
      return q > 0 ? Math.round(-2 * Math.log2(q)) / 2 : 0;
    }

    // ---- colour
    const VIRIDIS = [[68, 1, 84], [71, 45, 123], [59, 82, 139], [44, 114, 142], [33, 145, 140], [40, 174, 128],
                     [94, 201, 98], [173, 220, 48], [253, 231, 37]];
    const RDBU = [[5, 48, 97], [42, 113, 178], [107, 172, 209], [194, 221, 236], [247, 246, 246], [251, 204, 180],
                  [228, 128, 102], [186, 40, 50], [103, 0, 31]];
    const REJECTED = [255, 0, 255];
    function ramp(map, t) {  // t in [0, 1]
      if (!(t > 0)) t = 0;
      if (t > 1) t = 1;
      const x = t * (map.length - 1), i = Math.min(Math.floor(x), map.length - 2), f = x - i;
      return [0, 1, 2].map((c) => Math.round(map[i][c] + f * (map[i + 1][c] - map[i][c])));
    }
    function srgb8(v) {  // linear -> 8-bit sRGB, clipped to [0, 1]
      v = v > 0 ? (v < 1 ? v : 1) : 0;
      return Math.round(255 * (v <= 0.0031308 ? 12.92 * v : 1.055 * Math.pow(v, 1 / 2.4) - 0.055));
    }
    function blockIndex(x, y) {
      return Math.floor(y * blocks.rows / H) * blocks.cols + Math.floor(x * blocks.cols / W);
    }
    function blockP(index) {  // the smallest p-value over channels (null: no data)
      let p = null;
      for (let c = 0; c < blocks.channels; c++) {
        const v = blocks.p[index * blocks.channels + c];
        if (v !== null && (p === null || v < p)) p = v;
      }
      return p;
    }
    function blockColour(p) {  // -log10 p from 0 (p = 1) to -log10 threshold, rejected blocks magenta
      if (p === null) return [128, 128, 128];
      if (p < blocks.threshold) return REJECTED;
      return ramp(VIRIDIS, Math.log10(Math.max(p, 1e-300)) / Math.log10(blocks.threshold));
    }

    // ---- state and elements
    const canvas = document.getElementById("canvas"), ctx = canvas.getContext("2d");
    const offscreen = document.createElement("canvas");
    offscreen.width = W; offscreen.height = H;
    const offCtx = offscreen.getContext("2d"), pixels = offCtx.createImageData(W, H);
    const el = (id) => document.getElementById(id);
    const exposureInput = el("exposure"), transformSelect = el("transform"), outline = el("outline");
    const state = { view: 0, scale: 1, tx: 0, ty: 0, fitted: true, cursor: null, pointer: null, drag: null };
    if (!blocks) el("outline-group").style.display = "none";

    function paint() {
      const v = views[state.view], d = v.data, px = pixels.data, k = Math.pow(2, v.exposure);
      for (let p = 0; p < N; p++) {
        let rgb;
        if (v.kind === "blocks") {
          rgb = blockColour(blockP(blockIndex(p % W, Math.floor(p / W))));
        } else if (v.transform === "srgb") {
          rgb = [srgb8(d[3 * p] * k), srgb8(d[3 * p + 1] * k), srgb8(d[3 * p + 2] * k)];
        } else if (v.transform === "signed") {
          rgb = ramp(RDBU, 0.5 + 0.5 * k * (d[3 * p] + d[3 * p + 1] + d[3 * p + 2]) / 3);
        } else {
          rgb = ramp(VIRIDIS, k * (Math.abs(d[3 * p]) + Math.abs(d[3 * p + 1]) + Math.abs(d[3 * p + 2])) / 3);
        }
        px[4 * p] = rgb[0]; px[4 * p + 1] = rgb[1]; px[4 * p + 2] = rgb[2]; px[4 * p + 3] = 255;
      }
      offCtx.putImageData(pixels, 0, 0);
      draw();
    }

    function draw() {
      const dpr = window.devicePixelRatio || 1;
      ctx.setTransform(1, 0, 0, 1, 0, 0);
      ctx.fillStyle = "#3a3a3a";
      ctx.fillRect(0, 0, canvas.width, canvas.height);
      ctx.imageSmoothingEnabled = false;  // nearest neighbour: each image pixel a sharp square
      ctx.setTransform(dpr * state.scale, 0, 0, dpr * state.scale, dpr * state.tx, dpr * state.ty);
      ctx.drawImage(offscreen, 0, 0);
      const line = 1 / state.scale;
      if (state.scale >= 24) {  // pixel grid
        ctx.strokeStyle = "rgba(128,128,128,0.35)";
        ctx.lineWidth = line;
        ctx.beginPath();
        for (let x = 0; x <= W; x++) { ctx.moveTo(x, 0); ctx.lineTo(x, H); }
        for (let y = 0; y <= H; y++) { ctx.moveTo(0, y); ctx.lineTo(W, y); }
        ctx.stroke();
      }
      if (blocks && outline.checked && views[state.view].kind !== "blocks") {
        ctx.strokeStyle = "rgb(255,0,255)";
        ctx.lineWidth = 2 * line;
        for (let r = 0; r < blocks.rows; r++) {
          for (let c = 0; c < blocks.cols; c++) {
            const p = blockP(r * blocks.cols + c);
            if (p === null || p >= blocks.threshold) continue;
            const x0 = c * W / blocks.cols, y0 = r * H / blocks.rows;
            ctx.strokeRect(x0, y0, W / blocks.cols, H / blocks.rows);
          }
        }
      }
      if (state.cursor && state.scale >= 4) {
        ctx.strokeStyle = "rgb(255,255,0)";
        ctx.lineWidth = 2 * line;
        ctx.strokeRect(state.cursor[0], state.cursor[1], 1, 1);
      }
      el("zoom-value").textContent = "zoom " + formatZoom(state.scale);
    }

    function formatZoom(s) {
      return s >= 1 ? (Number.isInteger(s) ? s : s.toFixed(2)) + "\u00d7" : "1/" + (1 / s).toFixed(2);
    }

    // ---- geometry: image pixel (x, y) covers canvas CSS pixels [tx + x s, tx + (x + 1) s)
    // The canvas's backing store follows its CSS size (times the device pixel ratio) whenever the layout
    // changes it, so that the browser never rescales the bitmap.
    function resize() {
      const dpr = window.devicePixelRatio || 1, width = canvas.getBoundingClientRect().width;
      const height = Math.round(Math.min(Math.max(width * H / W, 240), 0.7 * window.innerHeight));
      if (canvas.style.height !== height + "px") canvas.style.height = height + "px";
      const backingWidth = Math.round(width * dpr), backingHeight = Math.round(height * dpr);
      if (canvas.width !== backingWidth || canvas.height !== backingHeight) {
        canvas.width = backingWidth;
        canvas.height = backingHeight;
      }
      if (state.fitted) fit(); else draw();
    }
    function fit() {
      const w = canvas.clientWidth, h = canvas.clientHeight;
      state.scale = Math.min(w / W, h / H);
      if (state.scale > 1) state.scale = Math.floor(state.scale);  // whole screen pixels per image pixel
      state.tx = Math.round((w - W * state.scale) / 2);
      state.ty = Math.round((h - H * state.scale) / 2);
      state.fitted = true;
      draw();
    }
    function zoomAt(factor, cx, cy) {  // cx, cy: canvas CSS pixels that stay put
      const scale = Math.min(Math.max(state.scale * factor, 0.05), 512);
      state.tx = cx - (cx - state.tx) * scale / state.scale;
      state.ty = cy - (cy - state.ty) * scale / state.scale;
      state.scale = scale;
      state.fitted = false;
      if (state.pointer) locate(state.pointer[0], state.pointer[1]);
      draw();
    }
    function zoomKey(factor) {
      const p = state.pointer || [canvas.clientWidth / 2, canvas.clientHeight / 2];
      zoomAt(factor, p[0], p[1]);
    }
    function locate(cx, cy) {  // the image pixel under canvas point (cx, cy), or null
      const x = Math.floor((cx - state.tx) / state.scale), y = Math.floor((cy - state.ty) / state.scale);
      state.cursor = x >= 0 && y >= 0 && x < W && y < H ? [x, y] : null;
      readout();
    }

    // ---- the readout: every image's linear RGB at the cursor pixel
    function formatFloat32(v) {  // the shortest decimal that reads back as the same float32
      if (!Number.isFinite(v)) return String(v);
      for (let digits = 1; digits < 9; digits++) {
        const s = v.toPrecision(digits);
        if (Math.fround(Number(s)) === v) return s;
      }
      return v.toPrecision(9);
    }
    function readout() {
      const box = el("readout"), at = state.cursor;
      box.classList.toggle("stale", !at);
      if (!at && box.firstChild) return;  // keeps the last pixel's values, greyed
      const p = at ? at[1] * W + at[0] : 0;
      let rows = "";
      views.forEach((v, i) => {
        if (v.kind === "blocks") return;
        const cls = i === state.view ? ' class="current"' : "";
        rows += "<tr" + cls + "><th title=\"" + escapeHtml(v.name) + "\">" + (i + 1) + " " + escapeHtml(v.label) + "</th>";
        for (let c = 0; c < 3; c++) {
          const value = at ? formatFloat32(v.data[3 * p + c]) : "\u2013";
          rows += '<td data-view="' + i + '" data-channel="' + c + '">' + value + "</td>";
        }
        rows += "</tr>";
      });
      let html = '<p id="readout-pixel">' + (at ? "pixel (" + at[0] + ", " + at[1] + ")" : "move the mouse over the image") +
                 "</p><table><thead><tr><th></th><th>R</th><th>G</th><th>B</th></tr></thead><tbody>" + rows +
                 "</tbody></table>";
      if (blocks && at) {
        const b = blockIndex(at[0], at[1]), r = Math.floor(b / blocks.cols), c = b % blocks.cols, ps = [];
        for (let ch = 0; ch < blocks.channels; ch++) {
          const v = blocks.p[b * blocks.channels + ch];
          ps.push(v === null ? "\u2013" : v.toPrecision(3));
        }
        const pmin = blockP(b);
        const verdict = pmin === null ? "no data" : pmin < blocks.threshold ? "<strong>rejected</strong>" : "not rejected";
        html += '<p id="readout-block">' + escapeHtml(blocks.label) + ", block (" + r + ", " + c + "): p = " +
                ps.join(", ") + "; " + verdict + " at p &lt; " + blocks.threshold.toPrecision(3) + "</p>";
      }
      box.innerHTML = html;
    }
    function escapeHtml(s) {
      return s.replace(/&/g, "&amp;").replace(/</g, "&lt;").replace(/>/g, "&gt;").replace(/"/g, "&quot;");
    }

    // ---- controls
    function select(i) {
      if (i < 0 || i >= views.length) return;
      state.view = i;
      document.querySelectorAll("#view-buttons button").forEach((b, j) => b.classList.toggle("active", j === i));
      syncControls();
      paint();
      readout();
    }
    function setExposure(e) {
      views[state.view].exposure = Math.min(Math.max(Math.round(e * 10) / 10, -20), 20);
      syncControls();
      paint();
    }
    function setTransform(t) {
      views[state.view].transform = t;
      syncControls();
      paint();
    }
    function syncControls() {
      const v = views[state.view], isBlocks = v.kind === "blocks";
      exposureInput.value = v.exposure;
      exposureInput.disabled = transformSelect.disabled = isBlocks;
      el("exposure-value").textContent = isBlocks ? "" : (v.exposure >= 0 ? "+" : "") + v.exposure.toFixed(1) + " EV";
      if (!isBlocks) transformSelect.value = v.transform;
      legend(v);
    }
    function legend(v) {
      const bar = el("legend-bar"), g = bar.getContext("2d"), k = Math.pow(2, -v.exposure);
      let text, map = null;
      if (v.kind === "blocks") {
        map = (t) => (t >= 1 ? REJECTED : ramp(VIRIDIS, t));
        text = "p from 1 (left) to " + blocks.threshold.toPrecision(3) + " on a log scale; magenta: rejected (p < " +
               blocks.threshold.toPrecision(3) + " in some channel); grey: no data";
      } else if (v.transform === "signed") {
        map = (t) => ramp(RDBU, t);
        text = "mean of R, G, B from \u2212" + formatFloat32(Math.fround(k)) + " (blue) through 0 to +" +
               formatFloat32(Math.fround(k)) + " (red)";
      } else if (v.transform === "magnitude") {
        map = (t) => ramp(VIRIDIS, t);
        text = "mean of |R|, |G|, |B| from 0 to " + formatFloat32(Math.fround(k));
      } else {
        text = "linear \u00d7 2^" + v.exposure.toFixed(1) + ", sRGB-encoded, clipped at " + formatFloat32(Math.fround(k));
      }
      bar.style.display = map ? "" : "none";
      if (map) {
        for (let i = 0; i < bar.width; i++) {
          const c = map(v.kind === "blocks" ? (i < bar.width - 16 ? i / (bar.width - 17) : 1) : i / (bar.width - 1));
          g.fillStyle = "rgb(" + c[0] + "," + c[1] + "," + c[2] + ")";
          g.fillRect(i, 0, 1, bar.height);
        }
      }
      el("legend-text").textContent = text;
    }

    const buttons = el("view-buttons");
    views.forEach((v, i) => {
      const b = document.createElement("button");
      b.textContent = (i + 1) + " " + v.label;
      b.title = v.name + " (key " + (i + 1) + ")";
      b.addEventListener("click", () => { select(i); b.blur(); });
      buttons.appendChild(b);
    });
    exposureInput.addEventListener("input", () => setExposure(Number(exposureInput.value)));
    transformSelect.addEventListener("change", () => setTransform(transformSelect.value));
    outline.addEventListener("change", draw);
    for (const control of [exposureInput, transformSelect, outline]) {  // the keys go back to the viewer
      control.addEventListener("change", () => control.blur());
    }
    el("zoom-in").addEventListener("click", () => zoomKey(2));
    el("zoom-out").addEventListener("click", () => zoomKey(0.5));
    el("zoom-fit").addEventListener("click", fit);
    el("zoom-one").addEventListener("click", () => zoomKey(1 / state.scale));

    function canvasPoint(e) {
      const r = canvas.getBoundingClientRect();
      return [e.clientX - r.left, e.clientY - r.top];
    }
    canvas.addEventListener("mousemove", (e) => {
      const [cx, cy] = canvasPoint(e);
      if (state.drag) {
        state.tx = state.drag[2] + cx - state.drag[0];
        state.ty = state.drag[3] + cy - state.drag[1];
        state.fitted = false;
      }
      state.pointer = [cx, cy];
      locate(cx, cy);
      draw();
    });
    canvas.addEventListener("mouseleave", () => { state.pointer = null; state.drag = null; });
    canvas.addEventListener("mousedown", (e) => {
      const [cx, cy] = canvasPoint(e);
      state.drag = [cx, cy, state.tx, state.ty];
      e.preventDefault();
    });
    window.addEventListener("mouseup", () => { state.drag = null; });
    canvas.addEventListener("dblclick", fit);
    canvas.addEventListener("wheel", (e) => {
      const [cx, cy] = canvasPoint(e);
      zoomAt(Math.pow(2, -e.deltaY / 240), cx, cy);
      e.preventDefault();
    }, { passive: false });

    document.addEventListener("keydown", (e) => {
      if (e.ctrlKey || e.metaKey || e.altKey) return;
      const tag = e.target && e.target.tagName;
      if (tag === "INPUT" || tag === "SELECT" || tag === "TEXTAREA") return;
      const key = e.key;
      if (key >= "1" && key <= "9") select(Number(key) - 1);
      else if (key === "ArrowRight") select((state.view + 1) % views.length);
      else if (key === "ArrowLeft") select((state.view + views.length - 1) % views.length);
      else if (key === "+" || key === "=") setExposure(views[state.view].exposure + 0.5);
      else if (key === "-" || key === "_") setExposure(views[state.view].exposure - 0.5);
      else if (key === "0") setExposure(views[state.view].defaultExposure);
      else if (key === "z") zoomKey(2);
      else if (key === "x") zoomKey(0.5);
      else if (key === "f") fit();
      else if (key === "t" && views[state.view].kind !== "blocks") {
        const order = ["srgb", "signed", "magnitude"];
        setTransform(order[(order.indexOf(views[state.view].transform) + 1) % order.length]);
      } else if (key === "b" && blocks) { outline.checked = !outline.checked; draw(); }
      else return;
      e.preventDefault();
    });
    window.addEventListener("resize", resize);
    new ResizeObserver(resize).observe(canvas);

    // For tests and the console: where image point (x, y) lies in the window's client coordinates.
    window.viewer = {
      views: views.map((v) => v.name),
      state: state,
      imageToClient: function (x, y) {
        const r = canvas.getBoundingClientRect();
        return [r.left + state.tx + x * state.scale, r.top + state.ty + y * state.scale];
      },
    };

    resize();
    select(0);
  }
})();
