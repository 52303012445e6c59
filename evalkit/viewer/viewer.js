// The reports' HDR image comparison viewer (evalkit/viewer.py writes its markup and data).
//
// Each <div class="ek-viewer" data-group='{...}'> is one group of images of one size: a method's
// test image, the reference, error maps. One canvas shows one image at a time, so zoom, pan and
// exposure are shared by the whole group; the readout lists every image's value at the cursor.
// Pixel data are half floats (RGB, row 0 at the top) in a script per image,
// viewer/<name>.js, which calls evalkitViewer.loaded(); a group's scripts are added when it
// first scrolls into view, so a large report opens quickly from file:// with no server.
//
// Keys (over a viewer, or after clicking it): 1-9 an image, Left/Right or [ ] the previous/next,
// Space the image shown before (flip), E / Shift+E exposure +/- 0.5 stop, + / - zoom,
// 0 fit, R reset exposure. Mouse: wheel zooms at the cursor, drag pans, a click flips.
"use strict";

const evalkitViewer = (() => {
  const data = {}; // name -> {width, height, pixels: Float32Array}
  const waiting = {}; // name -> callbacks
  const viewers = [];
  let active = null; // the viewer keys go to

  function halfToFloat(h) {
    const s = h & 0x8000 ? -1 : 1;
    const e = (h >> 10) & 0x1f;
    const f = h & 0x3ff;
    if (e === 0) return s * Math.pow(2, -14) * (f / 1024);
    if (e === 31) return f ? NaN : s * Infinity;
    return s * Math.pow(2, e - 15) * (1 + f / 1024);
  }

  function loaded(name, width, height, base64) {
    const bytes = Uint8Array.from(atob(base64), (c) => c.charCodeAt(0));
    const halves = new Uint16Array(bytes.buffer);
    const pixels = new Float32Array(halves.length);
    for (let i = 0; i < halves.length; i++) pixels[i] = halfToFloat(halves[i]);
    data[name] = { width, height, pixels };
    (waiting[name] || []).forEach((callback) => callback());
    delete waiting[name];
  }

  function load(name, src, callback) {
    if (data[name]) return callback();
    if (!waiting[name]) {
      waiting[name] = [];
      const script = document.createElement("script");
      script.src = src;
      document.head.appendChild(script);
    }
    waiting[name].push(callback);
  }

  function srgb(x) {
    x = Math.min(Math.max(x, 0), 1);
    return 255 * (x <= 0.0031308 ? 12.92 * x : 1.055 * Math.pow(x, 1 / 2.4) - 0.055) + 0.5;
  }

  function format(v) {
    return Number.isFinite(v) ? v.toPrecision(5) : String(v);
  }

  class Viewer {
    constructor(root) {
      this.root = root;
      this.group = JSON.parse(root.dataset.group);
      this.images = this.group.images;
      this.index = 0;
      this.previous = 0;
      this.exposure = this.group.exposure || 0;
      this.fit = true;
      this.scale = 1;
      this.offset = [0, 0];
      this.cursor = null;
      this.build();
    }

    build() {
      const g = this.group;
      this.root.tabIndex = 0;
      this.root.innerHTML = "";
      const bar = document.createElement("div");
      bar.className = "ek-bar";
      this.buttons = this.images.map((image, i) => {
        const b = document.createElement("button");
        b.textContent = `${i + 1} ${image.label}`;
        b.onclick = () => this.show(i);
        bar.appendChild(b);
        return b;
      });
      this.exposureText = document.createElement("span");
      this.exposureText.className = "ek-exposure";
      this.zoomText = document.createElement("span");
      this.zoomText.className = "ek-zoom";
      bar.append(this.exposureText, this.zoomText);
      this.canvas = document.createElement("canvas");
      this.canvas.width = g.display[0];
      this.canvas.height = g.display[1];
      this.colorbar = document.createElement("canvas");
      this.colorbar.className = "ek-colorbar";
      this.colorbar.width = 256;
      this.colorbar.height = 12;
      this.colorbarText = document.createElement("span");
      this.readout = document.createElement("table");
      this.readout.className = "ek-readout";
      const side = document.createElement("div");
      side.className = "ek-side";
      side.append(this.readout, this.colorbar, this.colorbarText);
      const main = document.createElement("div");
      main.className = "ek-main";
      main.append(this.canvas, side);
      this.root.append(bar, main);
      this.root.dataset.state = "waiting";
      this.listen();
      this.update();
    }

    start() {
      if (this.started) return;
      this.started = true;
      this.root.dataset.state = "loading";
      // The shown image first, then the others (the readout lists them all).
      const order = [this.index, ...this.images.keys()].filter((v, i, a) => a.indexOf(v) === i);
      order.forEach((i) => load(this.images[i].name, this.images[i].src, () => this.update()));
    }

    show(i) {
      if (i < 0 || i >= this.images.length || i === this.index) return;
      this.previous = this.index;
      this.index = i;
      this.start();
      this.update();
    }

    setScale(scale, at) {
      const [ax, ay] = at || [this.canvas.width / 2, this.canvas.height / 2];
      const old = this.currentScale();
      this.fit = false;
      this.scale = Math.min(Math.max(scale, 0.05), 64);
      const k = this.scale / old;
      this.offset = [ax - (ax - this.offset[0]) * k, ay - (ay - this.offset[1]) * k];
      this.update();
    }

    currentScale() {
      if (!this.fit) return this.scale;
      const [w, h] = this.group.size;
      const s = Math.min(this.canvas.width / w, this.canvas.height / h);
      this.offset = [(this.canvas.width - w * s) / 2, (this.canvas.height - h * s) / 2];
      return s;
    }

    // The image pixel under canvas point (cx, cy), or null.
    pixelAt(cx, cy) {
      const s = this.currentScale();
      const x = Math.floor((cx - this.offset[0]) / s);
      const y = Math.floor((cy - this.offset[1]) / s);
      const [w, h] = this.group.size;
      return x >= 0 && y >= 0 && x < w && y < h ? [x, y] : null;
    }

    listen() {
      const c = this.canvas;
      let drag = null;
      const point = (e) => {
        const r = c.getBoundingClientRect();
        return [((e.clientX - r.left) * c.width) / r.width, ((e.clientY - r.top) * c.height) / r.height];
      };
      this.root.addEventListener("mouseenter", () => (active = this));
      this.root.addEventListener("mousedown", () => (active = this));
      c.addEventListener("wheel", (e) => {
        e.preventDefault();
        this.setScale(this.currentScale() * (e.deltaY < 0 ? 1.25 : 0.8), point(e));
      });
      c.addEventListener("mousedown", (e) => (drag = { at: point(e), moved: false }));
      window.addEventListener("mouseup", () => {
        if (drag && !drag.moved) this.show(this.previous);
        drag = null;
      });
      c.addEventListener("mousemove", (e) => {
        const p = point(e);
        if (drag) {
          const dx = p[0] - drag.at[0];
          const dy = p[1] - drag.at[1];
          if (Math.abs(dx) + Math.abs(dy) > 2 || drag.moved) {
            this.scale = this.currentScale();
            this.fit = false;
            this.offset = [this.offset[0] + dx, this.offset[1] + dy];
            drag = { at: p, moved: true };
          }
        }
        this.cursor = this.pixelAt(p[0], p[1]);
        this.update();
      });
      c.addEventListener("mouseleave", () => {
        this.cursor = null;
        this.update();
      });
    }

    key(e) {
      const k = e.key;
      if (k >= "1" && k <= "9") this.show(Number(k) - 1);
      else if (k === "ArrowRight" || k === "]") this.show((this.index + 1) % this.images.length);
      else if (k === "ArrowLeft" || k === "[") this.show((this.index + this.images.length - 1) % this.images.length);
      else if (k === " ") this.show(this.previous);
      else if (k === "e") this.setExposure(this.exposure + 0.5);
      else if (k === "E") this.setExposure(this.exposure - 0.5);
      else if (k === "r" || k === "R") this.setExposure(this.group.exposure || 0);
      else if (k === "+" || k === "=") this.setScale(this.currentScale() * 2);
      else if (k === "-") this.setScale(this.currentScale() / 2);
      else if (k === "0") {
        this.fit = true;
        this.update();
      } else return;
      e.preventDefault();
    }

    setExposure(value) {
      this.exposure = value;
      this.update();
    }

    update() {
      const image = this.images[this.index];
      this.buttons.forEach((b, i) => b.classList.toggle("ek-on", i === this.index));
      this.exposureText.textContent = image.colormap
        ? `error map 0..${format(image.vmax)}`
        : `exposure ${this.exposure >= 0 ? "+" : ""}${this.exposure.toFixed(1)}`;
      this.root.dataset.exposure = String(this.exposure);
      this.root.dataset.index = String(this.index);
      const s = this.currentScale();
      this.zoomText.textContent = `zoom ${Math.round(s * 100)} %${this.fit ? " (fit)" : ""}`;
      this.root.dataset.scale = String(s);
      this.draw(image, s);
      this.drawReadout();
      this.drawColorbar(image);
    }

    draw(image, s) {
      const ctx = this.canvas.getContext("2d");
      ctx.fillStyle = "#333";
      ctx.fillRect(0, 0, this.canvas.width, this.canvas.height);
      const d = data[image.name];
      if (!d) return;
      const key = `${image.name}|${this.exposure}`;
      if (this.cacheKey !== key) {
        const off = document.createElement("canvas");
        off.width = d.width;
        off.height = d.height;
        const octx = off.getContext("2d");
        const pixels = octx.createImageData(d.width, d.height);
        const scale = Math.pow(2, this.exposure);
        for (let i = 0, j = 0; i < d.pixels.length; i += 3, j += 4) {
          if (image.colormap) {
            const t = Math.min(Math.max(d.pixels[i] / image.vmax, 0), 1);
            const c = image.colormap[Math.round(t * (image.colormap.length - 1))];
            pixels.data.set([c[0], c[1], c[2], 255], j);
          } else {
            pixels.data.set([srgb(d.pixels[i] * scale), srgb(d.pixels[i + 1] * scale), srgb(d.pixels[i + 2] * scale), 255], j);
          }
        }
        octx.putImageData(pixels, 0, 0);
        this.cached = off;
        this.cacheKey = key;
      }
      ctx.imageSmoothingEnabled = false;
      ctx.drawImage(this.cached, this.offset[0], this.offset[1], d.width * s, d.height * s);
      const ready = this.images.every((im) => data[im.name]);
      this.root.dataset.state = ready ? "ready" : "loading";
      this.root.dataset.shown = image.name;
    }

    drawReadout() {
      const rows = [];
      const at = this.cursor;
      this.root.dataset.cursor = at ? `${at[0]},${at[1]}` : "";
      rows.push(`<tr><th>${at ? `x ${at[0]}, y ${at[1]}` : "pixel"}</th><th>R</th><th>G</th><th>B</th></tr>`);
      this.images.forEach((image, i) => {
        const d = data[image.name];
        let cells = "<td></td><td></td><td></td>";
        if (d && at) {
          const k = 3 * (at[1] * d.width + at[0]);
          const v = image.colormap ? [d.pixels[k]] : [d.pixels[k], d.pixels[k + 1], d.pixels[k + 2]];
          cells = v.map((x) => `<td>${format(x)}</td>`).join("") + (image.colormap ? "<td></td><td></td>" : "");
        }
        const label = `${i + 1} ${image.label}`;
        rows.push(`<tr class="${i === this.index ? "ek-on" : ""}" data-image="${i}"><th>${label}</th>${cells}</tr>`);
      });
      this.readout.innerHTML = rows.join("");
    }

    drawColorbar(image) {
      this.colorbar.style.display = image.colormap ? "" : "none";
      this.colorbarText.textContent = image.colormap ? `0 .. ${format(image.vmax)} (${image.label})` : "";
      if (!image.colormap) return;
      const ctx = this.colorbar.getContext("2d");
      image.colormap.forEach((c, i) => {
        ctx.fillStyle = `rgb(${c[0]},${c[1]},${c[2]})`;
        ctx.fillRect((i * 256) / image.colormap.length, 0, Math.ceil(256 / image.colormap.length), 12);
      });
    }
  }

  function init() {
    document.querySelectorAll(".ek-viewer").forEach((root) => viewers.push(new Viewer(root)));
    const visible = (entries) =>
      entries.forEach((entry) => entry.isIntersecting && viewers.find((v) => v.root === entry.target).start());
    if ("IntersectionObserver" in window) {
      const observer = new IntersectionObserver(visible, { rootMargin: "200px" });
      viewers.forEach((v) => observer.observe(v.root));
    } else viewers.forEach((v) => v.start());
    window.addEventListener("keydown", (e) => active && active.key(e));
    if (viewers.length) active = viewers[0];
  }

  document.addEventListener("DOMContentLoaded", init);
  return { loaded, viewers };
})();
