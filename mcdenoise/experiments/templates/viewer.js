/* The interactive HDR image viewer of the mcdenoise experiment report.
 *
 * Written by mcdenoise/experiments/viewer.py, which also documents the data: each scene's
 * viewer/scene_NN.js (named by the viewer's data-src, loaded when the viewer comes into view)
 * calls mcdViewerRegister({...}) with the scene's images as base64 zlib streams of half floats
 * (low-byte plane, then high-byte plane; CHW) and FLIP maps as uint8.
 * No library and no network: pixels are decoded with DecompressionStream("deflate") and a
 * half->float table, tonemapped (exposure in EV, clamp, sRGB) into an image-sized canvas, and
 * drawn into the panes with nearest-neighbour scaling, so zoom shows single pixels crisply.
 *
 * With #viewer-selftest in the page's URL, once everything has loaded the script zooms and
 * changes the exposure of the first viewer through the same event handlers as the mouse and
 * the slider, and writes what the canvas showed before and after, the number of decoded
 * images and every error caught into <pre id="viewer-selftest"> (the browser tests read it).
 */
(function () {
  "use strict";
  if (window.mcdViewerRegister) return; // the script is named once per scene section

  var REFERENCE = "reference";
  var NOISY = "noisy";
  var SELFTEST = window.location.hash === "#viewer-selftest";
  var ERRORS = [];
  var COUNTS = { colour: 0, flip: 0 };
  var VIEWERS = [];
  var ACTIVE = null;

  // --- errors: kept for the self-test and shown in a viewer's notes ----------------------

  function noteError(msg) {
    ERRORS.push(String(msg).slice(0, 400));
  }
  window.addEventListener(
    "error",
    function (e) {
      var t = e.target;
      if (t && t !== window && (t.src || t.href)) {
        noteError("could not load " + (t.getAttribute("src") || t.getAttribute("href")));
      } else {
        noteError("error: " + (e.message || "unknown") + " (" + (e.filename || "") + ":" +
          (e.lineno || "") + ")");
      }
    },
    true
  );
  window.addEventListener("unhandledrejection", function (e) {
    var r = e.reason;
    noteError("unhandled rejection: " + (r && r.message ? r.message : r));
  });
  var consoleError = console.error;
  console.error = function () {
    noteError("console.error: " + Array.prototype.map.call(arguments, String).join(" "));
    return consoleError.apply(console, arguments);
  };

  // --- decoding ------------------------------------------------------------------------

  var HALF = (function () {
    var t = new Float32Array(65536);
    for (var h = 0; h < 65536; h++) {
      var s = h & 0x8000 ? -1 : 1, e = (h >> 10) & 31, m = h & 1023;
      if (e === 0) t[h] = s * m * Math.pow(2, -24);
      else if (e === 31) t[h] = m ? NaN : s * Infinity;
      else t[h] = s * (1 + m / 1024) * Math.pow(2, e - 15);
    }
    return t;
  })();

  var SRGB_N = 16384;
  var SRGB = (function () {
    var t = new Uint8ClampedArray(SRGB_N + 1);
    for (var i = 0; i <= SRGB_N; i++) {
      var x = i / SRGB_N;
      t[i] = Math.round(255 * (x <= 0.0031308 ? 12.92 * x : 1.055 * Math.pow(x, 1 / 2.4) - 0.055));
    }
    return t;
  })();

  function base64Bytes(text) {
    var bin = window.atob(text), n = bin.length, out = new Uint8Array(n);
    for (var i = 0; i < n; i++) out[i] = bin.charCodeAt(i);
    return out;
  }

  function inflate(bytes) {
    var stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
    return new Response(stream).arrayBuffer();
  }

  /* A colour layer -> Uint16Array of half floats (CHW); a FLIP layer -> Uint8Array (HW). */
  function decodeLayer(text, kind, expected) {
    return inflate(base64Bytes(text)).then(function (buf) {
      var b = new Uint8Array(buf);
      if (kind === "flip") {
        if (b.length !== expected) throw new Error("FLIP layer of " + b.length + " bytes");
        COUNTS.flip++;
        return b;
      }
      var n = b.length >> 1;
      if (n !== expected) throw new Error("colour layer of " + n + " values, not " + expected);
      var out = new Uint16Array(n);
      for (var i = 0; i < n; i++) out[i] = b[i] | (b[n + i] << 8);
      COUNTS.colour++;
      return out;
    });
  }

  // --- small DOM helpers -----------------------------------------------------------------

  function el(tag, attrs, children) {
    var e = document.createElement(tag);
    Object.keys(attrs || {}).forEach(function (k) {
      if (k === "text") e.textContent = attrs[k];
      else if (k === "cls") e.className = attrs[k];
      else e.setAttribute(k, attrs[k]);
    });
    (children || []).forEach(function (c) {
      e.appendChild(typeof c === "string" ? document.createTextNode(c) : c);
    });
    return e;
  }

  function fmt(v) {
    if (v !== v) return "NaN";
    if (!isFinite(v)) return v > 0 ? "+Inf" : "-Inf";
    var a = Math.abs(v);
    return a !== 0 && (a < 1e-3 || a >= 1e5) ? v.toExponential(3) : v.toPrecision(4);
  }

  // --- one viewer per scene --------------------------------------------------------------

  function Viewer(root, data) {
    var self = this;
    this.root = root;
    this.d = data;
    this.W = data.width;
    this.H = data.height;
    this.n = data.width * data.height;
    this.byKey = {};
    data.images.forEach(function (img) {
      img.key = img.label === REFERENCE ? REFERENCE : img.label + "@" + img.spp;
      self.byKey[img.key] = img;
    });
    this.cache = {};
    this.token = 0;
    this.lut = new Uint8Array(data.colormap);
    var methods = data.labels.filter(function (l) { return l !== NOISY && l !== REFERENCE; });
    var first = methods.length ? methods[0] : data.labels[0];
    this.s = {
      a: { label: first, spp: data.strip_spp },
      b: { label: REFERENCE, spp: null }, // spp null: the same level as A
      mode: "split",
      shown: "a",
      view: "image",
      ev: 0,
      frame: Math.floor(data.frames / 2),
      zoom: 1,
      cx: this.W / 2,
      cy: this.H / 2,
      crop: -1,
      before: null, // what `r` flipped away from
    };
    this.build();
    this.layout();
    this.reset();
    var pending = this.render();
    this.ready = pending.then(function () { return self.prefetch(); });
  }

  Viewer.prototype.build = function () {
    var self = this, d = this.d, s = this.s, app = this.root.querySelector(".mcdv-app");
    app.textContent = "";
    this.root.tabIndex = 0;
    var bar1 = el("div", { cls: "mcdv-bar" }, [el("b", { text: "A" })]);
    this.aButtons = d.labels.map(function (label, i) {
      var key = label === REFERENCE ? "r" : i < 9 ? String(i + 1) : "";
      var b = el("button", { type: "button", title: key ? "key " + key : "" },
        [key ? el("span", { cls: "mcdv-key", text: key }) : "", label]);
      b.addEventListener("click", function () { self.setA(label); });
      bar1.appendChild(b);
      return b;
    });
    var bar2 = el("div", { cls: "mcdv-bar" }, [el("b", { text: "spp" })]);
    this.levelButtons = d.levels.map(function (spp) {
      var b = el("button", { type: "button", text: String(spp) });
      b.addEventListener("click", function () { self.setLevel(spp); });
      bar2.appendChild(b);
      return b;
    });
    bar2.appendChild(el("b", { text: "B" }));
    this.bLabel = el("select", { "aria-label": "image B" },
      d.labels.map(function (l) { return el("option", { value: l, text: l }); }));
    this.bLabel.addEventListener("change", function () {
      s.b.label = self.bLabel.value; s.before = null; self.render();
    });
    this.bSpp = el("select", { "aria-label": "spp of image B" },
      [el("option", { value: "", text: "same spp as A" })].concat(d.levels.map(function (v) {
        return el("option", { value: String(v), text: v + " spp" });
      })));
    this.bSpp.addEventListener("change", function () {
      s.b.spp = self.bSpp.value ? Number(self.bSpp.value) : null; self.render();
    });
    bar2.appendChild(this.bLabel);
    bar2.appendChild(this.bSpp);

    var bar3 = el("div", { cls: "mcdv-bar" });
    function group(name, items, onClick) {
      bar3.appendChild(el("b", { text: name }));
      return items.map(function (it) {
        var b = el("button", { type: "button", text: it[1], title: it[2] || "" });
        b.addEventListener("click", function () { onClick(it[0]); });
        bar3.appendChild(b);
        return b;
      });
    }
    this.modeButtons = group("show", [["split", "A | B", "side by side (key s)"],
      ["single", "one at a time", "flip with f or space (key s)"]], function (m) { self.setMode(m); });
    var views = [["image", "image"], ["relmse", "relMSE", "relative squared error (key e)"]];
    views.push(["flip", "FLIP", d.flip_note ? "not available: " + d.flip_note
      : "HDR-FLIP at " + d.flip_spp + " spp (key e)"]);
    this.viewButtons = group("view", views, function (v) { self.setView(v); });
    if (d.flip_note) this.viewButtons[2].disabled = true;
    var crops = [[-1, "whole image", "key 0"]].concat(d.crops.map(function (c, i) {
      return [i, "crop " + (i + 1), c.w + "×" + c.h + " px at x " + c.x + ", y " + c.y +
        ": where the methods disagree most at " + d.crop_spp + " spp (key c)"];
    }));
    this.cropButtons = group("zoom", crops, function (i) { self.setCrop(i); });
    bar3.appendChild(el("b", { text: "exposure" }));
    this.evInput = el("input", { type: "range", min: "-10", max: "10", step: "0.1", value: "0",
      "aria-label": "exposure in EV" });
    this.evInput.addEventListener("input", function () { self.setEV(Number(self.evInput.value)); });
    this.evText = el("span", { cls: "mcdv-num" });
    bar3.appendChild(this.evInput);
    bar3.appendChild(this.evText);
    var bars = [bar1, bar2, bar3];
    if (d.frames > 1) {
      var bar4 = el("div", { cls: "mcdv-bar" }, [el("b", { text: "frame" })]);
      this.frameInput = el("input", { type: "range", min: "0", max: String(d.frames - 1),
        step: "1", value: String(s.frame), "aria-label": "frame" });
      this.frameInput.addEventListener("input", function () {
        self.setFrame(Number(self.frameInput.value));
      });
      this.frameText = el("span", { cls: "mcdv-num" });
      bar4.appendChild(this.frameInput);
      bar4.appendChild(this.frameText);
      bars.push(bar4);
    }
    var panes = el("div", { cls: "mcdv-panes" });
    this.panes = [0, 1].map(function () {
      var cap = el("div", { cls: "mcdv-cap" }), canvas = el("canvas");
      var fig = el("figure", { cls: "mcdv-pane" }, [cap, canvas]);
      panes.appendChild(fig);
      self.attach(canvas);
      return { fig: fig, cap: cap, canvas: canvas, off: null, msg: "", cur: null };
    });
    this.status = el("div", { cls: "mcdv-status" });
    this.legend = el("div", { cls: "mcdv-legend" });
    this.notes = el("p", { cls: "notes" });
    var notes = d.notes.slice();
    if (d.flip_note) notes.push("FLIP not available: " + d.flip_note);
    this.notes.textContent = notes.join(" · ");
    this.notes.style.display = notes.length ? "" : "none";
    bars.concat([panes, this.legend, this.status, this.notes]).forEach(function (e) {
      app.appendChild(e);
    });
    this.root.addEventListener("pointerenter", function () { ACTIVE = self; });
    this.root.addEventListener("focusin", function () { ACTIVE = self; });
    window.addEventListener("resize", function () { self.layout(); self.draw(); });
  };

  /* Mouse: wheel zooms about the cursor, drag pans, double-click resets, hover reads values. */
  Viewer.prototype.attach = function (canvas) {
    var self = this, drag = null;
    function pos(e) {
      var r = canvas.getBoundingClientRect();
      return [e.clientX - r.left, e.clientY - r.top];
    }
    canvas.addEventListener("wheel", function (e) {
      e.preventDefault();
      var dy = e.deltaY * (e.deltaMode === 1 ? 33 : e.deltaMode === 2 ? 400 : 1);
      var p = pos(e);
      self.zoomAt(p[0], p[1], Math.pow(2, -dy / 300));
    }, { passive: false });
    canvas.addEventListener("pointerdown", function (e) {
      ACTIVE = self;
      drag = pos(e);
      canvas.setPointerCapture(e.pointerId);
    });
    canvas.addEventListener("pointermove", function (e) {
      var p = pos(e);
      if (drag) {
        self.s.cx -= (p[0] - drag[0]) / self.s.zoom;
        self.s.cy -= (p[1] - drag[1]) / self.s.zoom;
        drag = p;
        self.draw();
      }
      self.readout(p[0], p[1]);
    });
    canvas.addEventListener("pointerup", function () { drag = null; });
    canvas.addEventListener("pointercancel", function () { drag = null; });
    canvas.addEventListener("pointerleave", function () { self.readout(null, null); });
    canvas.addEventListener("dblclick", function () { self.setCrop(-1); });
  };

  Viewer.prototype.layout = function () {
    var width = this.root.clientWidth || 800;
    var pw = Math.max(160, Math.min(640, Math.floor((width - 40) / 2)));
    var ph = Math.round(pw * this.H / this.W);
    if (ph > 640) { ph = 640; pw = Math.round(640 * this.W / this.H); }
    var dpr = window.devicePixelRatio || 1;
    this.pw = pw; this.ph = ph;
    this.panes.forEach(function (p) {
      p.canvas.style.width = pw + "px";
      p.canvas.style.height = ph + "px";
      p.canvas.width = Math.round(pw * dpr);
      p.canvas.height = Math.round(ph * dpr);
      p.cap.style.width = pw + "px";
    });
    this.fit = Math.min(pw / this.W, ph / this.H);
  };

  Viewer.prototype.reset = function () {
    this.s.zoom = this.fit;
    this.s.cx = this.W / 2;
    this.s.cy = this.H / 2;
    this.s.crop = -1;
  };

  Viewer.prototype.zoomAt = function (px, py, factor) {
    var s = this.s;
    var ix = s.cx + (px - this.pw / 2) / s.zoom, iy = s.cy + (py - this.ph / 2) / s.zoom;
    var z = Math.min(Math.max(s.zoom * factor, this.fit / 4), Math.max(64, this.fit * 4));
    s.cx = ix - (px - this.pw / 2) / z;
    s.cy = iy - (py - this.ph / 2) / z;
    s.zoom = z;
    s.crop = -2; // free view
    this.draw();
    this.updateUI();
  };

  // --- state changes (buttons, keys and the self-test all come through these) ------------

  Viewer.prototype.setA = function (label) {
    this.s.a.label = label;
    this.s.shown = "a";
    this.s.before = null;
    this.render();
  };
  Viewer.prototype.setLevel = function (spp) { this.s.a.spp = spp; this.render(); };
  Viewer.prototype.setMode = function (m) { this.s.mode = m; this.s.shown = "a"; this.render(); };
  Viewer.prototype.setView = function (v) {
    if (v === "flip" && this.d.flip_note) return;
    this.s.view = v;
    this.render();
  };
  Viewer.prototype.setEV = function (ev) {
    this.s.ev = Math.max(-10, Math.min(10, ev));
    this.evInput.value = String(this.s.ev);
    return this.render();
  };
  Viewer.prototype.setFrame = function (t) {
    this.s.frame = Math.max(0, Math.min(this.d.frames - 1, t));
    if (this.frameInput) this.frameInput.value = String(this.s.frame);
    this.render();
  };
  Viewer.prototype.setCrop = function (i) {
    var c = this.d.crops[i];
    if (!c) { this.reset(); }
    else {
      this.s.zoom = Math.min(this.pw / c.w, this.ph / c.h);
      this.s.cx = c.x + c.w / 2;
      this.s.cy = c.y + c.h / 2;
      this.s.crop = i;
    }
    this.draw();
    this.updateUI();
  };

  /* `r`: the shown image (one at a time) or B (side by side) becomes the reference; again: back. */
  Viewer.prototype.toggleReference = function () {
    var s = this.s, slot = s.mode === "single" ? s[s.shown] : s.b;
    if (slot.label === REFERENCE && s.before) { slot.label = s.before; s.before = null; }
    else if (slot.label !== REFERENCE) { s.before = slot.label; slot.label = REFERENCE; }
    this.render();
  };

  /* `f`, space: one at a time, show the other image; side by side, swap the sides. */
  Viewer.prototype.flip = function () {
    var s = this.s;
    if (s.mode === "single") s.shown = s.shown === "a" ? "b" : "a";
    else {
      var label = s.a.label;
      s.a.label = s.b.label;
      s.b.label = label;
      if (s.b.spp !== null) { var spp = s.a.spp; s.a.spp = s.b.spp; s.b.spp = spp; }
    }
    this.render();
  };

  Viewer.prototype.key = function (e) {
    var s = this.s, d = this.d, k = e.key, labels = d.labels;
    var inA = labels.indexOf(s.a.label), lv = d.levels.indexOf(s.a.spp);
    if (k >= "1" && k <= "9") {
      var i = Number(k) - 1;
      if (i < labels.length && labels[i] !== REFERENCE) this.setA(labels[i]);
    } else if (k === "ArrowRight" || k === "ArrowLeft") {
      var step = k === "ArrowRight" ? 1 : -1;
      this.setA(labels[(inA + step + labels.length) % labels.length]);
    } else if (k === "ArrowUp" || k === "ArrowDown") {
      var j = Math.max(0, Math.min(d.levels.length - 1, lv + (k === "ArrowUp" ? 1 : -1)));
      this.setLevel(d.levels[j]);
    } else if (k === "r" || k === "R") this.toggleReference();
    else if (k === "f" || k === "F" || k === " ") this.flip();
    else if (k === "s" || k === "S") this.setMode(s.mode === "split" ? "single" : "split");
    else if (k === "e" || k === "E") {
      var views = d.flip_note ? ["image", "relmse"] : ["image", "relmse", "flip"];
      this.setView(views[(views.indexOf(s.view) + 1) % views.length]);
    } else if (k === "c" || k === "C") {
      this.setCrop(d.crops.length ? (s.crop + 2) % (d.crops.length + 1) - 1 : -1);
    } else if (k === "0") this.setCrop(-1);
    else if (k === "[" || k === "]") this.setEV(s.ev + (k === "]" ? 0.5 : -0.5));
    else if (k === "," || k === ".") this.setFrame(s.frame + (k === "." ? 1 : -1));
    else if (k === "+" || k === "=" || k === "-") {
      this.zoomAt(this.pw / 2, this.ph / 2, k === "-" ? 0.5 : 2);
    } else return false;
    return true;
  };

  document.addEventListener("keydown", function (e) {
    var v = ACTIVE || (VIEWERS.length === 1 ? VIEWERS[0] : null);
    var t = e.target && e.target.tagName;
    if (!v || e.ctrlKey || e.metaKey || e.altKey || t === "SELECT" || t === "TEXTAREA" ||
        (t === "INPUT" && e.key.indexOf("Arrow") === 0)) return;
    try {
      if (v.key(e)) e.preventDefault();
    } catch (err) { noteError("key " + e.key + ": " + err.message); }
  });

  // --- what the panes show ---------------------------------------------------------------

  Viewer.prototype.entry = function (slot) {
    if (slot.label === REFERENCE) return this.byKey[REFERENCE];
    var spp = slot.spp === null ? this.s.a.spp : slot.spp;
    return this.byKey[slot.label + "@" + spp] || { label: slot.label, spp: spp,
      missing: "not stored in this report" };
  };

  Viewer.prototype.layer = function (entry, kind, frame) {
    var list = entry && !entry.missing ? (kind === "flip" ? entry.flip : entry.frames) : null;
    if (!list || !list[frame]) return Promise.resolve(null);
    var key = entry.key + "|" + kind + "|" + frame;
    if (!this.cache[key]) {
      var self = this;
      this.cache[key] = decodeLayer(list[frame], kind, kind === "flip" ? this.n : 3 * this.n)
        .catch(function (err) {
          noteError("decoding " + entry.key + ": " + err.message);
          delete self.cache[key];
          return null;
        });
    }
    return this.cache[key];
  };

  Viewer.prototype.shownSlots = function () {
    var s = this.s;
    if (s.mode === "single") return [{ side: s.shown.toUpperCase(), slot: s[s.shown] }];
    return [{ side: "A", slot: s.a }, { side: "B", slot: s.b }];
  };

  Viewer.prototype.render = function () {
    var self = this, s = this.s, token = ++this.token, f = s.frame;
    var ref = this.byKey[REFERENCE];
    var jobs = this.shownSlots().map(function (p) {
      var e = self.entry(p.slot);
      var flip = s.view === "flip" && e.label !== REFERENCE ? self.layer(e, "flip", f) : null;
      return Promise.all([self.layer(e, "colour", f), self.layer(ref, "colour", f), flip])
        .then(function (r) { return { side: p.side, e: e, px: r[0], ref: r[1], flip: r[2] }; });
    });
    this.pending = Promise.all(jobs).then(function (res) {
      if (token !== self.token) return;
      self.panes.forEach(function (pane, i) {
        pane.fig.style.display = i < res.length ? "" : "none";
        if (i < res.length) self.paint(pane, res[i]);
      });
      self.draw();
      self.updateUI();
    }).catch(function (err) { noteError("render: " + (err && err.message)); });
    return this.pending;
  };

  Viewer.prototype.paint = function (pane, r) {
    var s = this.s, e = r.e, n = this.n, view = s.view;
    var spp = e.label === REFERENCE ? "" : ", " + e.spp + " spp";
    var head = r.side + ": " + e.label + spp, extra = "";
    pane.cur = r;
    if (e.missing || !r.px) {
      pane.off = null;
      pane.nonfinite = 0;
      pane.msg = e.label + spp.replace(",", " at") + ": not available (" +
        (e.missing || "could not be decoded") + ")";
      pane.cap.textContent = head + " — not available";
      pane.cap.title = pane.msg;
      return;
    }
    if (e.label === REFERENCE || !r.ref) view = "image";
    if (view === "flip" && !r.flip) view = "image";
    var off = pane.off || el("canvas");
    off.width = this.W; off.height = this.H;
    var ctx = off.getContext("2d"), img = ctx.createImageData(this.W, this.H), d = img.data;
    var px = r.px, bad = 0, i, o, c;
    if (view === "image") {
      var mult = this.d.exposure * Math.pow(2, s.ev);
      for (i = 0; i < n; i++) {
        o = 4 * i;
        var R = HALF[px[i]] * mult, G = HALF[px[n + i]] * mult, B = HALF[px[2 * n + i]] * mult;
        if (R - R !== 0 || G - G !== 0 || B - B !== 0) { // NaN or Inf: magenta
          d[o] = 255; d[o + 1] = 0; d[o + 2] = 255; bad++;
        } else {
          d[o] = SRGB[R <= 0 ? 0 : R >= 1 ? SRGB_N : (R * SRGB_N + 0.5) | 0];
          d[o + 1] = SRGB[G <= 0 ? 0 : G >= 1 ? SRGB_N : (G * SRGB_N + 0.5) | 0];
          d[o + 2] = SRGB[B <= 0 ? 0 : B >= 1 ? SRGB_N : (B * SRGB_N + 0.5) | 0];
        }
        d[o + 3] = 255;
      }
    } else {
      var lut = this.lut, lo = Math.log10(this.d.error_scale[0]);
      var span = Math.log10(this.d.error_scale[1]) - lo;
      for (i = 0; i < n; i++) {
        var v = view === "flip" ? r.flip[i] / 255 : this.relmse(px, r.ref, i);
        var t = view === "flip" ? v : (Math.log10(v) - lo) / span; // log10(0) = -Inf -> 0
        o = 4 * i;
        if (v !== v || t === Infinity) { d[o] = 255; d[o + 1] = 0; d[o + 2] = 255; bad++; }
        else {
          c = 3 * Math.round(255 * Math.max(0, Math.min(1, t)));
          d[o] = lut[c]; d[o + 1] = lut[c + 1]; d[o + 2] = lut[c + 2];
        }
        d[o + 3] = 255;
      }
    }
    ctx.putImageData(img, 0, 0);
    pane.off = off;
    pane.msg = "";
    pane.nonfinite = bad;
    if (bad) extra = " [" + bad + " px NaN/Inf: magenta]";
    extra += view === "relmse" ? " [relMSE map]" : view === "flip" ? " [FLIP map]" : "";
    if (s.view === "flip" && view !== "flip" && e.label !== REFERENCE) {
      extra += " [no FLIP: " + (e.flip_missing || this.d.flip_note ||
        "FLIP maps are stored at " + this.d.flip_spp + " spp only") + "]";
    }
    pane.cap.textContent = head + (e.caption ? " — " + e.caption : "") + extra;
    pane.cap.title = pane.cap.textContent;
  };

  /* relMSE of one pixel: (x - r)^2 / (r^2 + 0.01), averaged over the channels. */
  Viewer.prototype.relmse = function (px, ref, i) {
    var n = this.n, sum = 0;
    for (var c = 0; c < 3; c++) {
      var x = HALF[px[c * n + i]], r = HALF[ref[c * n + i]];
      sum += (x - r) * (x - r) / (r * r + 0.01);
    }
    return sum / 3;
  };

  Viewer.prototype.draw = function () {
    var s = this.s, dpr = window.devicePixelRatio || 1, self = this;
    this.panes.forEach(function (pane) {
      var c = pane.canvas, ctx = c.getContext("2d");
      ctx.setTransform(1, 0, 0, 1, 0, 0);
      ctx.fillStyle = "#202020";
      ctx.fillRect(0, 0, c.width, c.height);
      if (!pane.off) {
        ctx.fillStyle = "#ddd";
        ctx.font = Math.round(13 * dpr) + "px system-ui, sans-serif";
        self.wrap(ctx, pane.msg || "loading…", 12 * dpr, 24 * dpr, c.width - 24 * dpr, 18 * dpr);
        return;
      }
      var z = s.zoom * dpr;
      var ox = Math.round(c.width / 2 - s.cx * z), oy = Math.round(c.height / 2 - s.cy * z);
      ctx.imageSmoothingEnabled = false;
      ctx.setTransform(z, 0, 0, z, ox, oy);
      ctx.drawImage(pane.off, 0, 0);
      ctx.setTransform(1, 0, 0, 1, 0, 0);
      if (s.zoom <= self.fit * 1.5) {
        self.d.crops.forEach(function (cr, i) {
          ctx.strokeStyle = i === 0 ? "#00e5ff" : "#ffd600";
          ctx.lineWidth = Math.max(1, Math.round(dpr));
          ctx.strokeRect(ox + cr.x * z + 0.5, oy + cr.y * z + 0.5, cr.w * z - 1, cr.h * z - 1);
          ctx.fillStyle = ctx.strokeStyle;
          ctx.font = Math.round(12 * dpr) + "px system-ui, sans-serif";
          ctx.fillText(String(i + 1), ox + cr.x * z + 3 * dpr, oy + cr.y * z + 13 * dpr);
        });
      }
    });
  };

  Viewer.prototype.wrap = function (ctx, text, x, y, width, lh) {
    var line = "";
    text.split(" ").forEach(function (word) {
      if (line && ctx.measureText(line + " " + word).width > width) {
        ctx.fillText(line, x, y); y += lh; line = word;
      } else line = line ? line + " " + word : word;
    });
    ctx.fillText(line, x, y);
  };

  Viewer.prototype.readout = function (px, py) {
    var s = this.s;
    if (px === null) { this.status.textContent = this.zoomText(); return; }
    var x = Math.floor(s.cx + (px - this.pw / 2) / s.zoom);
    var y = Math.floor(s.cy + (py - this.ph / 2) / s.zoom);
    if (x < 0 || y < 0 || x >= this.W || y >= this.H) {
      this.status.textContent = this.zoomText(); return;
    }
    var i = y * this.W + x, n = this.n, self = this;
    var lines = ["pixel x " + x + ", y " + y + (this.d.frames > 1 ? ", frame " + s.frame : "")];
    this.panes.forEach(function (pane) {
      var r = pane.cur;
      if (pane.fig.style.display === "none" || !r) return;
      var name = r.side + " " + r.e.label + (r.e.label === REFERENCE ? "" : " " + r.e.spp + " spp");
      if (!r.px) { lines.push(name + ": not available"); return; }
      var rgb = [0, 1, 2].map(function (c) { return fmt(HALF[r.px[c * n + i]]); }).join(" ");
      var err = r.ref && r.e.label !== REFERENCE ? "  relMSE " + fmt(self.relmse(r.px, r.ref, i)) : "";
      if (r.flip) err += "  FLIP " + fmt(r.flip[i] / 255);
      lines.push(name + ": RGB " + rgb + err);
    });
    this.status.textContent = lines.join("\n");
  };

  Viewer.prototype.zoomText = function () {
    return "zoom " + this.s.zoom.toFixed(2) + "× (screen px per image px); " + this.W + "×" +
      this.H + " px";
  };

  Viewer.prototype.updateUI = function () {
    var s = this.s, d = this.d, self = this;
    var shownA = s.mode === "single" ? s[s.shown] : s.a;
    this.aButtons.forEach(function (b, i) { b.classList.toggle("on", d.labels[i] === shownA.label); });
    this.levelButtons.forEach(function (b, i) { b.classList.toggle("on", d.levels[i] === s.a.spp); });
    this.modeButtons[0].classList.toggle("on", s.mode === "split");
    this.modeButtons[1].classList.toggle("on", s.mode === "single");
    ["image", "relmse", "flip"].forEach(function (v, i) {
      self.viewButtons[i].classList.toggle("on", s.view === v);
    });
    this.cropButtons.forEach(function (b, i) { b.classList.toggle("on", s.crop === i - 1); });
    this.bLabel.value = s.b.label;
    this.bSpp.value = s.b.spp === null ? "" : String(s.b.spp);
    var mult = d.exposure * Math.pow(2, s.ev);
    this.evText.textContent = (s.ev >= 0 ? "+" : "") + s.ev.toFixed(1) + " EV (×" + fmt(mult) + ")";
    if (this.frameText) this.frameText.textContent = s.frame + " / " + (d.frames - 1);
    this.status.textContent = this.zoomText();
    if (this.legendView !== s.view) this.updateLegend();
  };

  Viewer.prototype.updateLegend = function () {
    var view = this.s.view, d = this.d;
    this.legendView = view;
    this.legend.textContent = "";
    if (view === "image") return;
    var bar = el("canvas", { width: "256", height: "1" });
    var ctx = bar.getContext("2d"), img = ctx.createImageData(256, 1);
    for (var i = 0; i < 256; i++) {
      img.data[4 * i] = this.lut[3 * i];
      img.data[4 * i + 1] = this.lut[3 * i + 1];
      img.data[4 * i + 2] = this.lut[3 * i + 2];
      img.data[4 * i + 3] = 255;
    }
    ctx.putImageData(img, 0, 0);
    var ticks = [];
    if (view === "flip") ticks = ["0", "0.25", "0.5", "0.75", "1"];
    else {
      var lo = Math.round(Math.log10(d.error_scale[0])), hi = Math.round(Math.log10(d.error_scale[1]));
      for (var e = lo; e <= hi; e++) ticks.push("1e" + e);
    }
    var title = view === "flip" ? "HDR-FLIP per pixel (linear, 0 = no visible difference)"
      : "relMSE per pixel, (x − r)² / (r² + 0.01) over the channels (log scale); magenta: NaN/Inf";
    this.legend.appendChild(el("div", { text: title }));
    this.legend.appendChild(el("div", { cls: "mcdv-scale" }, [bar, el("div", { cls: "mcdv-ticks" },
      ticks.map(function (t) { return el("span", { text: t }); }))]));
  };

  /* Decode every colour layer in the background: switching images is then instant. */
  Viewer.prototype.prefetch = function () {
    var self = this, jobs = [];
    this.d.images.forEach(function (e) {
      (e.frames || []).forEach(function (_, t) { jobs.push([e, t]); });
    });
    return jobs.reduce(function (p, job) {
      return p.then(function () { return self.layer(job[0], "colour", job[1]); });
    }, Promise.resolve());
  };

  // --- registration, missing data, self-test ---------------------------------------------

  window.mcdViewerRegister = function (data) {
    var root = document.getElementById("viewer-" + data.index);
    if (!root) { noteError("no element #viewer-" + data.index); return; }
    try {
      if (typeof DecompressionStream === "undefined") {
        throw new Error("this browser has no DecompressionStream (Chromium 80+, Firefox 113+)");
      }
      VIEWERS.push(new Viewer(root, data));
    } catch (err) {
      noteError("viewer " + data.index + ": " + err.message);
      var app = root.querySelector(".mcdv-app");
      if (app) app.textContent = "The viewer could not start: " + err.message;
    }
  };

  function docRect(e) {
    var r = e.getBoundingClientRect();
    return { x: Math.round(r.left + window.scrollX), y: Math.round(r.top + window.scrollY),
      w: Math.round(r.width), h: Math.round(r.height) };
  }

  function checksum(canvas) {
    var copy = el("canvas", { width: String(canvas.width), height: String(canvas.height) });
    var ctx = copy.getContext("2d", { willReadFrequently: true });
    ctx.drawImage(canvas, 0, 0);
    var d = ctx.getImageData(0, 0, canvas.width, canvas.height).data;
    var sum = 0, hash = 2166136261;
    for (var i = 0; i < d.length; i += 4) {
      sum += d[i] + d[i + 1] + d[i + 2];
      hash = Math.imul(hash ^ (d[i] | (d[i + 1] << 8) | (d[i + 2] << 16)), 16777619) >>> 0;
    }
    return { mean: sum / (3 * d.length / 4), hash: hash };
  }

  /* Every image of a viewer in every view, through the buttons: what each pane showed. */
  function tour(v, out) {
    out.shown = {};
    var steps = [];
    v.viewButtons.forEach(function (vb) {
      if (vb.disabled) return;
      v.aButtons.forEach(function (ab, i) {
        v.levelButtons.forEach(function (lb) {
          steps.push(function () {
            vb.click(); ab.click(); lb.click();
            return v.pending.then(function () {
              var pane = v.panes[0], e = pane.cur && pane.cur.e;
              if (!e) return;
              var key = v.s.view + ":" + (e.key || e.label + "@" + e.spp);
              out.shown[key] = pane.off ? "shown, " + pane.nonfinite + " NaN/Inf" : pane.msg;
            });
          });
        });
      });
    });
    return steps.reduce(function (p, step) { return p.then(step); }, Promise.resolve());
  }

  function runSelftest() {
    var out = { viewers: VIEWERS.length, images: 0, decoded: 0, flip_layers: 0 };
    VIEWERS.sort(function (x, y) { return x.d.index - y.d.index; });
    var v = VIEWERS[0];
    function finish() {
      out.decoded = COUNTS.colour;
      out.flip_layers = COUNTS.flip;
      out.errors = ERRORS.slice();
      if (v) { // where the first viewer is on the page (document pixels), for screenshots
        out.rect = docRect(v.root);
        out.pane = docRect(v.panes[0].canvas);
      }
      out.page_height = document.documentElement.scrollHeight;
      var pre = document.getElementById("viewer-selftest") || el("pre", { id: "viewer-selftest" });
      pre.textContent = JSON.stringify(out);
      document.body.appendChild(pre);
      // the same on the console: Firefox has no --dump-dom; its browser test reads this line
      // from stdout (devtools.console.stdout.content)
      console.log("viewer-selftest " + JSON.stringify(out));
    }
    VIEWERS.forEach(function (x) {
      x.d.images.forEach(function (e) { out.images += (e.frames || []).length; });
    });
    if (!v) { noteError("no viewer registered"); finish(); return; }
    Promise.all(VIEWERS.map(function (x) { return x.ready; })).then(function () {
      var canvas = v.panes[0].canvas, r = canvas.getBoundingClientRect();
      out.before = checksum(canvas);
      out.zoom_before = v.s.zoom;
      canvas.dispatchEvent(new WheelEvent("wheel", { deltaY: -600, deltaMode: 0,
        clientX: r.left + r.width / 2, clientY: r.top + r.height / 2, bubbles: true,
        cancelable: true }));
      out.zoom_after = v.s.zoom;
      out.after_zoom = checksum(canvas);
      v.evInput.value = "2";
      v.evInput.dispatchEvent(new Event("input", { bubbles: true }));
      return v.pending;
    }).then(function () {
      out.after_exposure = checksum(v.panes[0].canvas);
      ACTIVE = v;
      document.dispatchEvent(new KeyboardEvent("keydown", { key: "e", bubbles: true }));
      return v.pending;
    }).then(function () {
      out.view = v.s.view;
      out.after_error_view = checksum(v.panes[0].canvas);
      return tour(v, out);
    }).then(function () {
      finish();
    }).catch(function (err) { noteError("self-test: " + (err && err.message)); finish(); });
  }

  /* A scene's data (several MB) is loaded when its viewer comes near the window, so a long
     report holds in memory only the scenes looked at; the self-test loads them all. */
  var LOADS = [];
  function loadData(root) {
    var src = root.getAttribute("data-src");
    LOADS.push(new Promise(function (resolve) {
      var script = document.createElement("script");
      script.async = false; // run in page order
      script.src = src;
      script.onload = function () { soon(); resolve(); }; // the page grew: look again
      script.onerror = function () {
        var loading = root.querySelector(".mcdv-loading");
        if (loading) loading.textContent = "The viewer's data (" + src + ") did not load.";
        resolve();
      };
      document.body.appendChild(script);
    }));
  }
  /* Which viewers are within a screen of the window: measured on scroll and resize (no
     IntersectionObserver: it never fires where nothing is painted, as in headless runs). */
  var waiting = Array.prototype.slice.call(document.querySelectorAll(".mcdv[data-src]"));
  var timer = null;
  function loadNear() {
    timer = null;
    var h = window.innerHeight || 1000;
    waiting = waiting.filter(function (root) {
      var r = root.getBoundingClientRect();
      if (!SELFTEST && (r.bottom < -h || r.top > 2 * h)) return true;
      loadData(root);
      return false;
    });
    if (!waiting.length) {
      window.removeEventListener("scroll", soon);
      window.removeEventListener("resize", soon);
    }
  }
  function soon() { if (!timer) timer = setTimeout(loadNear, 100); }
  window.addEventListener("scroll", soon, { passive: true });
  window.addEventListener("resize", soon);
  loadNear();
  if (SELFTEST) {
    window.addEventListener("load", function () {
      Promise.all(LOADS).then(runSelftest);
    });
  }
})();
