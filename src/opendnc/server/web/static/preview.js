/* opendnc: the toolpath preview of a program version (docs/dashboard.md#preview).
   Reads the dry run's decimated toolpath (docs/check.md#toolpath-binary) with typed-array
   views and draws it with WebGL in one pass per kind: cutting moves in their tool's colour,
   rapids dashed, the stock (BLK FORM) as a box, the work zero as an axis cross. Orthographic
   camera: drag turns, Shift+drag or right-drag moves, the wheel zooms at the pointer; 3D, top,
   front and side views; a click on a move goes to its line (#L<n>), and a #L<n> anchor marks
   that line's moves. No library: a few hundred lines of our own. */
(function () {
  "use strict";

  var MAGIC = "ODTP";
  var NO_TOOL = 0xffffffff;
  var VIEWS = {  // azimuth and elevation of the eye, degrees (Z up; front looks along +Y)
    iso: [35, 30],
    top: [0, 90],
    front: [0, 0],
    side: [90, 0]
  };
  var DEG = Math.PI / 180;

  function css(name, fallback) {
    var value = getComputedStyle(document.documentElement).getPropertyValue(name).trim();
    return value || fallback;
  }

  function rgb(hex) {
    var m = /^#?([0-9a-f]{2})([0-9a-f]{2})([0-9a-f]{2})$/i.exec(hex);
    return m ? [parseInt(m[1], 16), parseInt(m[2], 16), parseInt(m[3], 16)] : [80, 80, 80];
  }

  function parse(buffer) {
    var head = new DataView(buffer);
    if (buffer.byteLength < 20) throw new Error("the toolpath is cut short");
    var magic = String.fromCharCode(head.getUint8(0), head.getUint8(1), head.getUint8(2), head.getUint8(3));
    if (magic !== MAGIC || head.getUint32(4, true) !== 1) throw new Error("not a toolpath of format 1");
    var metaLen = head.getUint32(8, true);
    var runCount = head.getUint32(12, true);
    var pointCount = head.getUint32(16, true);
    if (buffer.byteLength !== 20 + metaLen + 16 * runCount + 16 * pointCount) {
      throw new Error("the toolpath's size does not match its counts");
    }
    var meta = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 20, metaLen)));
    var at = 20 + metaLen;
    var runs = new Uint32Array(buffer, at, 4 * runCount);
    at += 16 * runCount;
    var points = new Float32Array(buffer, at, 3 * pointCount);
    at += 12 * pointCount;
    var lines = new Uint32Array(buffer, at, pointCount);
    return { meta: meta, runs: runs, points: points, lines: lines, count: pointCount };
  }

  var VERTEX = [
    "attribute vec3 aPos;",
    "attribute vec4 aColor;",
    "attribute float aDist;",
    "uniform mat4 uMvp;",
    "uniform float uSize;",
    "uniform float uBias;",
    "varying vec4 vColor;",
    "varying float vDist;",
    "void main() {",
    "  gl_Position = uMvp * vec4(aPos, 1.0);",
    "  gl_Position.z += uBias;",
    "  gl_PointSize = uSize;",
    "  vColor = aColor;",
    "  vDist = aDist;",
    "}"
  ].join("\n");
  var FRAGMENT = [
    "#ifdef GL_FRAGMENT_PRECISION_HIGH",
    "precision highp float;",
    "#else",
    "precision mediump float;",
    "#endif",
    "varying vec4 vColor;",
    "varying float vDist;",
    "uniform float uDash;",
    "uniform vec4 uTint;",
    "void main() {",
    "  if (uDash > 0.0 && fract(vDist / uDash) > 0.55) discard;",
    "  gl_FragColor = uTint.a > 0.0 ? uTint : vColor;",
    "}"
  ].join("\n");

  function compile(gl, type, source) {
    var shader = gl.createShader(type);
    gl.shaderSource(shader, source);
    gl.compileShader(shader);
    if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(shader));
    return shader;
  }

  function Preview(root) {
    this.root = root;
    this.canvas = root.querySelector("canvas");
    this.status = root.querySelector(".preview-status");
    this.view = "iso";
    this.azimuth = VIEWS.iso[0];
    this.elevation = VIEWS.iso[1];
    this.scale = 1;     // pixels per unit
    this.ox = 0;        // pan, pixels from the centre
    this.oy = 0;
    this.showRapids = true;
    this.showStock = true;
    this.marked = null; // point indices of the marked line
    this.frame = 0;
  }

  Preview.prototype.say = function (text) {
    this.status.textContent = text;
    this.status.hidden = !text;
  };

  Preview.prototype.start = function () {
    var self = this;
    var t0 = performance.now();
    performance.mark("preview-fetch");
    var reply = fetch(this.root.dataset.toolpath, { credentials: "same-origin" });
    try {
      // the context and its shaders while the toolpath is on its way (a task of its own)
      this.setup();
    } catch (error) {
      self.root.classList.add("failed");
      self.say(String(error.message || error));
      return Promise.resolve();
    }
    return reply
      .then(function (reply) {
        if (!reply.ok) {
          return reply.text().then(function (text) {
            throw new Error("the dry run failed (" + reply.status + ")" + (text.length < 200 ? ": " + text : ""));
          });
        }
        return reply.arrayBuffer();
      })
      .then(function (buffer) {
        self.fetched = performance.now() - t0;
        self.load(parse(buffer));
      })
      .catch(function (error) {
        self.root.classList.add("failed");
        self.say(String(error.message || error));
      });
  };

  Preview.prototype.setup = function () {
    var gl = this.canvas.getContext("webgl2", { antialias: false, preserveDrawingBuffer: false }) ||
      this.canvas.getContext("webgl", { antialias: false, preserveDrawingBuffer: false });
    if (!gl) throw new Error("this browser cannot draw the preview (no WebGL)");
    this.gl = gl;
    var indexType = gl.UNSIGNED_INT;
    if (!(typeof WebGL2RenderingContext !== "undefined" && gl instanceof WebGL2RenderingContext) &&
        !gl.getExtension("OES_element_index_uint")) {
      throw new Error("this browser cannot draw large toolpaths (no 32-bit indices)");
    }
    this.indexType = indexType;
    var program = gl.createProgram();
    gl.attachShader(program, compile(gl, gl.VERTEX_SHADER, VERTEX));
    gl.attachShader(program, compile(gl, gl.FRAGMENT_SHADER, FRAGMENT));
    gl.linkProgram(program);
    if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
    this.program = program;
    this.loc = {
      pos: gl.getAttribLocation(program, "aPos"),
      color: gl.getAttribLocation(program, "aColor"),
      dist: gl.getAttribLocation(program, "aDist"),
      mvp: gl.getUniformLocation(program, "uMvp"),
      size: gl.getUniformLocation(program, "uSize"),
      bias: gl.getUniformLocation(program, "uBias"),
      dash: gl.getUniformLocation(program, "uDash"),
      tint: gl.getUniformLocation(program, "uTint")
    };
    this.palette = [];
    for (var i = 0; i < 8; i++) this.palette.push(rgb(css("--tc" + i, "#1f5fbf")));
    this.rapidColor = rgb(css("--rapid", "#c2410c"));
  };

  Preview.prototype.load = function (path) {
    var t0 = performance.now();
    this.path = path;
    this.toolpath = this.buildPath(path);
    this.extras = this.buildExtras(path.meta);
    this.fit();
    this.bind();
    this.built = performance.now() - t0;
    this.draw();
    this.drawn = performance.now() - t0;
    performance.mark("preview-drawn");
    this.root.dataset.drawn = "1";
    var moves = path.meta.moves || 0;
    this.say(path.count ? "" : (moves ? "" : "No move to draw: the program never moves from a known position."));
    this.root.classList.add("ready");
    this.markHash();
  };

  Preview.prototype.buildPath = function (path) {
    var gl = this.gl;
    var runs = path.runs;
    var points = path.points;
    var count = path.count;
    var colors = new Uint8Array(4 * count);
    var dist = new Float32Array(count);
    var feeds = 0;
    var rapids = 0;
    var r;
    for (r = 0; r < runs.length; r += 4) {
      if (runs[r + 1] < 2) continue;
      if (runs[r + 2] & 1) rapids += runs[r + 1] - 1;
      else feeds += runs[r + 1] - 1;
    }
    var feedIdx = new Uint32Array(2 * feeds);
    var rapidIdx = new Uint32Array(2 * rapids);
    var f = 0;
    var q = 0;
    var low = [Infinity, Infinity, Infinity];
    var high = [-Infinity, -Infinity, -Infinity];
    for (r = 0; r < runs.length; r += 4) {
      var first = runs[r];
      var n = runs[r + 1];
      var rapid = runs[r + 2] & 1;
      var tool = runs[r + 3];
      var c = rapid ? this.rapidColor : (tool === NO_TOOL ? [110, 116, 128] : this.palette[tool % 8]);
      var along = 0;
      for (var k = 0; k < n; k++) {
        var i = first + k;
        var x = points[3 * i], y = points[3 * i + 1], z = points[3 * i + 2];
        if (x < low[0]) low[0] = x;
        if (x > high[0]) high[0] = x;
        if (y < low[1]) low[1] = y;
        if (y > high[1]) high[1] = y;
        if (z < low[2]) low[2] = z;
        if (z > high[2]) high[2] = z;
        colors[4 * i] = c[0];
        colors[4 * i + 1] = c[1];
        colors[4 * i + 2] = c[2];
        colors[4 * i + 3] = 255;
        if (k > 0) {
          var dx = x - points[3 * i - 3], dy = y - points[3 * i - 2], dz = z - points[3 * i - 1];
          along += Math.sqrt(dx * dx + dy * dy + dz * dz);
          if (rapid) { rapidIdx[q++] = i - 1; rapidIdx[q++] = i; }
          else { feedIdx[f++] = i - 1; feedIdx[f++] = i; }
        }
        dist[i] = along;
      }
    }
    this.low = low;
    this.high = high;
    return {
      pos: this.buffer(gl.ARRAY_BUFFER, points),
      color: this.buffer(gl.ARRAY_BUFFER, colors),
      dist: this.buffer(gl.ARRAY_BUFFER, dist),
      feeds: this.buffer(gl.ELEMENT_ARRAY_BUFFER, feedIdx),
      feedCount: feedIdx.length,
      rapids: this.buffer(gl.ELEMENT_ARRAY_BUFFER, rapidIdx),
      rapidCount: rapidIdx.length
    };
  };

  Preview.prototype.buffer = function (target, data) {
    var gl = this.gl;
    var buffer = gl.createBuffer();
    gl.bindBuffer(target, buffer);
    gl.bufferData(target, data, gl.STATIC_DRAW);
    return buffer;
  };

  Preview.prototype.buildExtras = function (meta) {
    // the stock's box and the work zero's axis cross, as plain coloured segments
    var low = this.low.slice();
    var high = this.high.slice();
    var stock = meta.stock;
    var segments = [];
    var colors = [];
    var stockColor = rgb(css("--stock", "#7c8796"));
    function seg(a, b, c) {
      segments.push(a[0], a[1], a[2], b[0], b[1], b[2]);
      colors.push(c[0], c[1], c[2], 255, c[0], c[1], c[2], 255);
    }
    var stockSegments = 0;
    if (stock && stock.min && stock.max) {
      var lo = stock.min;
      var hi = stock.max;
      var corners = [];
      for (var i = 0; i < 8; i++) {
        corners.push([i & 1 ? hi[0] : lo[0], i & 2 ? hi[1] : lo[1], i & 4 ? hi[2] : lo[2]]);
      }
      [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]]
        .forEach(function (e) { seg(corners[e[0]], corners[e[1]], stockColor); });
      stockSegments = 12;
      for (var a = 0; a < 3; a++) {
        low[a] = Math.min(low[a], lo[a]);
        high[a] = Math.max(high[a], hi[a]);
      }
    }
    if (!isFinite(low[0])) { low = [-1, -1, -1]; high = [1, 1, 1]; }
    var size = 0;
    for (var b = 0; b < 3; b++) size = Math.max(size, high[b] - low[b]);
    size = size || 1;
    var axis = size * 0.08;
    seg([0, 0, 0], [axis, 0, 0], [214, 40, 40]);
    seg([0, 0, 0], [0, axis, 0], [47, 158, 68]);
    seg([0, 0, 0], [0, 0, axis], [31, 95, 191]);
    for (var d = 0; d < 3; d++) {  // the frame holds the work zero too
      low[d] = Math.min(low[d], 0);
      high[d] = Math.max(high[d], 0);
    }
    this.low = low;
    this.high = high;
    var gl = this.gl;
    return {
      pos: this.buffer(gl.ARRAY_BUFFER, new Float32Array(segments)),
      color: this.buffer(gl.ARRAY_BUFFER, new Uint8Array(colors)),
      dist: this.buffer(gl.ARRAY_BUFFER, new Float32Array(segments.length / 3)),
      stock: stockSegments * 2,
      axes: 6
    };
  };

  Preview.prototype.basis = function () {
    var a = this.azimuth * DEG;
    var e = this.elevation * DEG;
    var eye = [Math.sin(a) * Math.cos(e), -Math.cos(a) * Math.cos(e), Math.sin(e)];
    var right = [Math.cos(a), Math.sin(a), 0];
    var up = [
      eye[1] * right[2] - eye[2] * right[1],
      eye[2] * right[0] - eye[0] * right[2],
      eye[0] * right[1] - eye[1] * right[0]
    ];
    return { eye: eye, right: right, up: up };
  };

  Preview.prototype.centre = function () {
    return [(this.low[0] + this.high[0]) / 2, (this.low[1] + this.high[1]) / 2, (this.low[2] + this.high[2]) / 2];
  };

  Preview.prototype.size = function () {
    var dpr = window.devicePixelRatio || 1;
    var w = Math.max(1, Math.round(this.canvas.clientWidth * dpr));
    var h = Math.max(1, Math.round(this.canvas.clientHeight * dpr));
    if (this.canvas.width !== w || this.canvas.height !== h) {
      this.canvas.width = w;
      this.canvas.height = h;
    }
    return [w, h, dpr];
  };

  Preview.prototype.fit = function () {
    // the whole frame in view: the box's corners projected, with a margin
    var b = this.basis();
    var c = this.centre();
    var x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
    for (var i = 0; i < 8; i++) {
      var p = [i & 1 ? this.high[0] : this.low[0], i & 2 ? this.high[1] : this.low[1], i & 4 ? this.high[2] : this.low[2]];
      var v = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
      var x = v[0] * b.right[0] + v[1] * b.right[1] + v[2] * b.right[2];
      var y = v[0] * b.up[0] + v[1] * b.up[1] + v[2] * b.up[2];
      x0 = Math.min(x0, x); x1 = Math.max(x1, x);
      y0 = Math.min(y0, y); y1 = Math.max(y1, y);
    }
    var s = this.size();
    var w = s[0] / s[2];
    var h = s[1] / s[2];
    this.scale = Math.min(0.9 * w / Math.max(x1 - x0, 1e-9), 0.9 * h / Math.max(y1 - y0, 1e-9));
    this.ox = -(x0 + x1) / 2 * this.scale;
    this.oy = -(y0 + y1) / 2 * this.scale;
  };

  Preview.prototype.matrix = function (w, h) {
    // orthographic: screen x = right.(p - c), y = up.(p - c), depth along the eye; w, h in CSS px
    var b = this.basis();
    var c = this.centre();
    var kx = 2 * this.scale / w;
    var ky = 2 * this.scale / h;
    var radius = 0;
    for (var i = 0; i < 3; i++) radius = Math.max(radius, this.high[i] - this.low[i]);
    var kz = 1 / Math.max(radius * 1.8, 1e-9);
    function dot(v) { return v[0] * c[0] + v[1] * c[1] + v[2] * c[2]; }
    var tx = -dot(b.right) * kx + 2 * this.ox / w;
    var ty = -dot(b.up) * ky + 2 * this.oy / h;
    var tz = dot(b.eye) * kz;
    return new Float32Array([
      b.right[0] * kx, b.up[0] * ky, -b.eye[0] * kz, 0,
      b.right[1] * kx, b.up[1] * ky, -b.eye[1] * kz, 0,
      b.right[2] * kx, b.up[2] * ky, -b.eye[2] * kz, 0,
      tx, ty, tz, 1
    ]);
  };

  Preview.prototype.redraw = function () {
    var self = this;
    if (this.frame) return;
    this.frame = requestAnimationFrame(function () {
      self.frame = 0;
      self.draw();
    });
  };

  Preview.prototype.attribs = function (set) {
    var gl = this.gl;
    var loc = this.loc;
    gl.bindBuffer(gl.ARRAY_BUFFER, set.pos);
    gl.enableVertexAttribArray(loc.pos);
    gl.vertexAttribPointer(loc.pos, 3, gl.FLOAT, false, 0, 0);
    gl.bindBuffer(gl.ARRAY_BUFFER, set.color);
    gl.enableVertexAttribArray(loc.color);
    gl.vertexAttribPointer(loc.color, 4, gl.UNSIGNED_BYTE, true, 0, 0);
    gl.bindBuffer(gl.ARRAY_BUFFER, set.dist);
    gl.enableVertexAttribArray(loc.dist);
    gl.vertexAttribPointer(loc.dist, 1, gl.FLOAT, false, 0, 0);
  };

  Preview.prototype.draw = function () {
    var gl = this.gl;
    var loc = this.loc;
    var s = this.size();
    var w = s[0] / s[2];
    var h = s[1] / s[2];
    gl.viewport(0, 0, s[0], s[1]);
    var bg = rgb(css("--preview-bg", "#fbfcfe"));
    gl.clearColor(bg[0] / 255, bg[1] / 255, bg[2] / 255, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.depthFunc(gl.LEQUAL);
    gl.useProgram(this.program);
    gl.uniformMatrix4fv(loc.mvp, false, this.matrix(w, h));
    gl.uniform1f(loc.size, 1);
    gl.uniform4f(loc.tint, 0, 0, 0, 0);
    var t = this.toolpath;
    this.attribs(t);
    // rapids a little behind: where a retract goes back up a drilled hole, the cut shows
    gl.uniform1f(loc.bias, 0);
    if (t.rapidCount && this.showRapids) {
      gl.uniform1f(loc.bias, 0.002);
      gl.uniform1f(loc.dash, 8 / this.scale);  // an 8-pixel period on screen, whatever the zoom
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, t.rapids);
      gl.drawElements(gl.LINES, t.rapidCount, this.indexType, 0);
      gl.uniform1f(loc.bias, 0);
    }
    gl.uniform1f(loc.dash, 0);
    if (t.feedCount) {
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, t.feeds);
      gl.drawElements(gl.LINES, t.feedCount, this.indexType, 0);
    }
    if (this.marked && this.marked.length) {
      gl.disable(gl.DEPTH_TEST);
      var mark = rgb(css("--mark", "#f08c00"));
      gl.uniform4f(loc.tint, mark[0] / 255, mark[1] / 255, mark[2] / 255, 1);
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, this.markBuffer);
      gl.drawElements(gl.LINES, this.marked.length, this.indexType, 0);
      gl.uniform1f(loc.size, 7 * s[2]);
      gl.drawElements(gl.POINTS, this.marked.length, this.indexType, 0);
      gl.uniform1f(loc.size, 1);
      gl.uniform4f(loc.tint, 0, 0, 0, 0);
      gl.enable(gl.DEPTH_TEST);
    }
    var e = this.extras;
    this.attribs(e);
    if (this.showStock && e.stock) gl.drawArrays(gl.LINES, 0, e.stock);
    gl.disable(gl.DEPTH_TEST);
    gl.drawArrays(gl.LINES, e.stock, e.axes);
  };

  Preview.prototype.setView = function (name) {
    var v = VIEWS[name];
    if (!v) return;
    this.view = name;
    this.azimuth = v[0];
    this.elevation = v[1];
    this.root.querySelectorAll("[data-view]").forEach(function (b) {
      b.setAttribute("aria-pressed", b.dataset.view === name ? "true" : "false");
    });
    this.fit();
    this.draw();
  };

  Preview.prototype.pick = function (cx, cy) {
    // the drawn segment nearest the pointer (within 6 px): the file line of the move there
    var rect = this.canvas.getBoundingClientRect();
    var m = this.matrix(rect.width, rect.height);
    var mx = cx - rect.left;
    var my = cy - rect.top;
    var hw = rect.width / 2;
    var hh = rect.height / 2;
    var best = 36;  // 6 px, squared
    var found = -1;
    var along = 0;
    var p = this.path.points;
    var runs = this.path.runs;
    for (var r = 0; r < runs.length; r += 4) {
      if ((runs[r + 2] & 1) && !this.showRapids) continue;
      var first = runs[r];
      var end = first + runs[r + 1];
      var ax = 0, ay = 0;
      for (var i = first; i < end; i++) {
        var x = p[3 * i], y = p[3 * i + 1], z = p[3 * i + 2];
        var bx = (m[0] * x + m[4] * y + m[8] * z + m[12] + 1) * hw;
        var by = (1 - (m[1] * x + m[5] * y + m[9] * z + m[13])) * hh;
        if (i > first) {
          var dx = bx - ax, dy = by - ay;
          var len2 = dx * dx + dy * dy;
          var t = len2 > 0 ? ((mx - ax) * dx + (my - ay) * dy) / len2 : 0;
          t = t < 0 ? 0 : (t > 1 ? 1 : t);
          var ex = ax + t * dx - mx, ey = ay + t * dy - my;
          var d = ex * ex + ey * ey;
          if (d < best) { best = d; found = i; along = t; }
        }
        ax = bx;
        ay = by;
      }
    }
    if (found < 0) return 0;
    var lines = this.path.lines;
    var a = lines[found - 1];
    var b = lines[found];
    // a drawn segment may stand for many merged moves of increasing lines: the one under
    // the pointer, as far along them as the pointer is along the segment
    if (b > a + 1) return a + Math.max(1, Math.ceil(along * (b - a)));
    return b;
  };

  Preview.prototype.mark = function (line) {
    // the moves of `line`: points of that line, or the drawn segment a dropped one lies on
    var path = this.path;
    var lines = path.lines;
    var runs = path.runs;
    var idx = [];
    for (var r = 0; r < runs.length && idx.length < 20000; r += 4) {
      var first = runs[r];
      var end = first + runs[r + 1];
      for (var i = first + 1; i < end; i++) {
        var a = lines[i - 1], b = lines[i];
        if (b === line || (a < line && line < b)) idx.push(i - 1, i);
      }
      if (runs[r + 1] === 1 && lines[first] === line) idx.push(first, first);
    }
    this.marked = idx;
    if (idx.length) {
      var gl = this.gl;
      if (!this.markBuffer) this.markBuffer = gl.createBuffer();
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, this.markBuffer);
      gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, new Uint32Array(idx), gl.DYNAMIC_DRAW);
    }
    var note = this.root.querySelector(".preview-note");
    note.textContent = idx.length ? "Line " + line : "Line " + line + ": no move drawn";
    note.hidden = false;
    this.redraw();
  };

  Preview.prototype.markHash = function () {
    var m = /^#L(\d+)$/.exec(location.hash);
    if (m) this.mark(parseInt(m[1], 10));
    else if (this.marked) {
      this.marked = null;
      this.root.querySelector(".preview-note").hidden = true;
      this.redraw();
    }
  };

  Preview.prototype.bind = function () {
    var self = this;
    var canvas = this.canvas;
    var drag = null;
    this.root.querySelectorAll("[data-view]").forEach(function (button) {
      button.addEventListener("click", function () { self.setView(button.dataset.view); });
    });
    this.root.querySelector("[data-fit]").addEventListener("click", function () { self.fit(); self.draw(); });
    var rapids = this.root.querySelector("[data-rapids]");
    rapids.addEventListener("change", function () { self.showRapids = rapids.checked; self.draw(); });
    var stock = this.root.querySelector("[data-stock]");
    stock.disabled = !(this.path.meta.stock);
    stock.addEventListener("change", function () { self.showStock = stock.checked; self.draw(); });
    canvas.addEventListener("contextmenu", function (event) { event.preventDefault(); });
    canvas.addEventListener("pointerdown", function (event) {
      canvas.setPointerCapture(event.pointerId);
      drag = { x: event.clientX, y: event.clientY, x0: event.clientX, y0: event.clientY,
        pan: event.shiftKey || event.button === 2 || event.button === 1 };
    });
    canvas.addEventListener("pointermove", function (event) {
      if (!drag) return;
      var dx = event.clientX - drag.x;
      var dy = event.clientY - drag.y;
      drag.x = event.clientX;
      drag.y = event.clientY;
      if (drag.pan) {
        self.ox += dx;
        self.oy -= dy;
      } else {
        self.azimuth -= dx * 0.4;
        self.elevation = Math.max(-90, Math.min(90, self.elevation + dy * 0.4));
        if (self.view !== "free") {
          self.view = "free";
          self.root.querySelectorAll("[data-view]").forEach(function (b) { b.setAttribute("aria-pressed", "false"); });
        }
      }
      self.redraw();
    });
    canvas.addEventListener("pointerup", function (event) {
      var moved = drag && Math.abs(event.clientX - drag.x0) + Math.abs(event.clientY - drag.y0) > 4;
      drag = null;
      if (!moved && event.button === 0) {
        var line = self.pick(event.clientX, event.clientY);
        if (line) location.hash = "#L" + line;
      }
    });
    canvas.addEventListener("wheel", function (event) {
      event.preventDefault();
      var rect = canvas.getBoundingClientRect();
      var mx = event.clientX - rect.left - rect.width / 2;
      var my = rect.height / 2 - (event.clientY - rect.top);
      var factor = Math.exp(-event.deltaY * (event.deltaMode === 1 ? 0.05 : 0.0015));
      // the point under the pointer stays there
      self.ox = mx - (mx - self.ox) * factor;
      self.oy = my - (my - self.oy) * factor;
      self.scale *= factor;
      self.redraw();
    }, { passive: false });
    canvas.addEventListener("keydown", function (event) {
      var step = { ArrowLeft: [-15, 0], ArrowRight: [15, 0], ArrowUp: [0, -15], ArrowDown: [0, 15] }[event.key];
      if (step) {
        event.preventDefault();
        self.azimuth -= step[0];
        self.elevation = Math.max(-90, Math.min(90, self.elevation - step[1]));
        self.redraw();
      } else if (event.key === "+" || event.key === "-") {
        self.scale *= event.key === "+" ? 1.25 : 0.8;
        self.ox *= event.key === "+" ? 1.25 : 0.8;
        self.oy *= event.key === "+" ? 1.25 : 0.8;
        self.redraw();
      }
    });
    window.addEventListener("hashchange", function () { self.markHash(); });
    if (typeof ResizeObserver !== "undefined") {
      var last = [canvas.clientWidth, canvas.clientHeight];
      new ResizeObserver(function () {
        if (canvas.clientWidth === last[0] && canvas.clientHeight === last[1]) return;
        last = [canvas.clientWidth, canvas.clientHeight];
        self.fit();
        self.redraw();
      }).observe(canvas);
    }
  };

  function start() {
    var root = document.querySelector(".preview-view");
    if (!root || !root.dataset.toolpath) return;
    var preview = new Preview(root);
    window.opendncPreview = preview;
    preview.start();
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();
