/* opendnc: the program text as a virtual list (docs/dashboard.md#program-text).
   The server renders one window of lines; this script fetches the whole version and draws
   only the rows in view inside a box of bounded height, so a program of a million lines is
   still a short page. It answers #L<n> anchors (and ?line=<n>), go-to-line, and find.
   Needs nchighlight.js (window.NcHighlight). */
(function () {
  "use strict";

  var MAX_PX = 8000000;  // browsers cap an element's height; beyond this the scroll is scaled
  var OVERSCAN = 20;     // rows drawn above and below the view
  var MAX_MATCHES = 200000;

  var DECODER = new TextDecoder("latin1");
  function latin1(buffer) {
    // NC programs are 7-bit text. The browser's "latin1" is windows-1252, which shows the
    // C1 control bytes 0x80-0x9F as other characters (the check reports such bytes anyway).
    return DECODER.decode(buffer);
  }

  function Listing(root) {
    this.root = root;
    this.box = root.querySelector(".listing-box");
    this.dialect = root.dataset.dialect || "gcode";
    // the program check's problems by line: [severity, message] (the rows are marked)
    this.marks = JSON.parse(root.dataset.marks || "{}");
    this.lines = null;
    this.hl = 0;
    this.matches = [];
    this.current = -1;
    this.query = "";
    this.pending = false;
    var self = this;
    var form = root.querySelector(".listing-bar");
    form.addEventListener("submit", function (event) {
      var n = parseInt(form.elements.line.value, 10);
      if (self.lines && n > 0) {
        event.preventDefault();
        self.anchor(n);
      }
    });
    var find = root.querySelector(".listing-find");
    this.findInput = find.querySelector("input");
    this.count = find.querySelector(".listing-count");
    var timer = 0;
    this.findInput.addEventListener("input", function () {
      clearTimeout(timer);
      timer = setTimeout(function () { self.search(self.findInput.value); }, 120);
    });
    this.findInput.addEventListener("keydown", function (event) {
      if (event.key === "Enter") {
        event.preventDefault();
        clearTimeout(timer);
        if (self.findInput.value !== self.query) self.search(self.findInput.value);
        else self.step(event.shiftKey ? -1 : 1);
      } else if (event.key === "Escape") {
        self.findInput.value = "";
        self.search("");
      }
    });
    find.querySelectorAll("[data-find]").forEach(function (button) {
      button.addEventListener("click", function () {
        self.step(parseInt(button.dataset.find, 10));
      });
    });
    root.addEventListener("keydown", function (event) {
      // find inside the virtual text: the browser's own find sees only the drawn rows
      if ((event.ctrlKey || event.metaKey) && event.key.toLowerCase() === "f" && self.lines) {
        event.preventDefault();
        self.findInput.focus();
        self.findInput.select();
      }
    });
    window.addEventListener("hashchange", function () {
      var n = Listing.hashLine();
      if (n) self.go(n, true);
    });
  }

  Listing.hashLine = function () {
    var m = /^#L(\d+)$/.exec(location.hash);
    return m ? parseInt(m[1], 10) : 0;
  };

  Listing.prototype.load = function (src) {
    var self = this;
    return fetch(src, { credentials: "same-origin" })
      .then(function (reply) {
        if (!reply.ok) throw new Error("the text could not be read (" + reply.status + ")");
        return reply.arrayBuffer();
      })
      .then(function (buffer) {
        performance.mark("listing-fetched");
        var lines = latin1(buffer).split(/\r\n|\r|\n/);
        if (lines.length > 1 && lines[lines.length - 1] === "") lines.pop();
        if (lines.length === 1 && lines[0] === "") lines = [];
        self.build(lines);
      });
  };

  Listing.prototype.build = function (lines) {
    this.lines = lines;
    var widest = 0;
    for (var i = 0; i < lines.length; i++) if (lines[i].length > widest) widest = lines[i].length;
    var digits = String(lines.length).length;
    this.root.style.setProperty("--digits", digits + 1);
    var box = this.box;
    box.innerHTML = "";
    box.classList.add("virtual");
    var spacer = document.createElement("div");
    spacer.className = "listing-spacer";
    var rows = document.createElement("div");
    rows.className = "listing-rows";
    rows.setAttribute("role", "list");
    spacer.appendChild(rows);
    box.appendChild(spacer);
    this.spacer = spacer;
    this.rows = rows;
    // one row measures the line height the CSS gives
    rows.innerHTML = '<div class="ln"><a class="no">0</a><span class="tx">0</span></div>';
    this.lh = rows.firstChild.getBoundingClientRect().height || 18;
    var full = lines.length * this.lh;
    this.height = Math.min(full, MAX_PX);
    spacer.style.height = this.height + "px";
    spacer.style.width = "calc(" + (widest + digits + 4) + "ch + 2rem)";
    var boxMax = parseFloat(getComputedStyle(box).maxHeight) || 600;
    box.style.height = Math.min(boxMax, Math.max(full, this.lh) + 2) + "px";
    var self = this;
    box.addEventListener("scroll", function () { self.schedule(); }, { passive: true });
    window.addEventListener("resize", function () { self.schedule(); });
    var pages = this.root.querySelector(".listing-pages");
    if (pages) pages.hidden = true;
    this.root.querySelector(".listing-find").hidden = false;
    this.render();
    this.root.classList.add("ready");
    performance.mark("listing-ready");
  };

  Listing.prototype.scale = function () {
    // virtual pixels of the text per pixel of the box's scroll range
    var view = this.box.clientHeight;
    var full = this.lines.length * this.lh;
    if (full <= this.height || this.height <= view) return 1;
    return (full - view) / (this.height - view);
  };

  Listing.prototype.schedule = function () {
    var self = this;
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(function () {
      self.pending = false;
      self.render();
    });
  };

  Listing.prototype.render = function () {
    var lines = this.lines;
    if (!lines) return;
    var lh = this.lh;
    var top = this.box.scrollTop;
    var virtualTop = top * this.scale();
    var first = Math.max(0, Math.floor(virtualTop / lh) - OVERSCAN);
    var count = Math.ceil(this.box.clientHeight / lh) + 2 * OVERSCAN;
    var last = Math.min(lines.length, first + count);
    // the rows sit where the scaled scroll puts the first of them
    this.rows.style.transform = "translateY(" + (top - (virtualTop - first * lh)) + "px)";
    var marks = this.marksFrom(first, last);
    var html = [];
    for (var i = first; i < last; i++) {
      var n = i + 1;
      var cls = n === this.hl ? "ln hl" : "ln";
      var mark = this.marks[n];
      var title = "";
      if (mark) {
        cls += " pb-" + mark[0];
        title = ' title="' + window.NcHighlight.escape(mark[1]) + '"';
      }
      html.push(
        '<div class="' + cls + '" id="L' + n + '" role="listitem"' + title + '><a class="no" href="#L' + n + '">' + n +
        '</a><span class="tx">' + window.NcHighlight.html(lines[i], this.dialect, marks[i]) + "</span></div>"
      );
    }
    this.rows.innerHTML = html.join("");
    this.first = first;
  };

  Listing.prototype.marksFrom = function (first, last) {
    var out = {};
    if (!this.query) return out;
    var size = this.query.length;
    // matches are sorted by line: find the first at or after `first`
    var lo = 0;
    var hi = this.matches.length;
    while (lo < hi) {
      var mid = (lo + hi) >> 1;
      if (this.matches[mid][0] < first) lo = mid + 1;
      else hi = mid;
    }
    for (var k = lo; k < this.matches.length && this.matches[k][0] < last; k++) {
      var m = this.matches[k];
      (out[m[0]] = out[m[0]] || []).push([m[1], m[1] + size, k === this.current]);
    }
    return out;
  };

  Listing.prototype.go = function (n, mark) {
    if (!this.lines || !this.lines.length) return;
    n = Math.max(1, Math.min(n, this.lines.length));
    if (mark) this.hl = n;
    var box = this.box;
    var top = ((n - 1) * this.lh) / this.scale() - box.clientHeight / 3;
    box.scrollTop = Math.max(0, top);
    var rect = box.getBoundingClientRect();
    if (rect.top < 0 || rect.bottom > window.innerHeight) {
      box.scrollIntoView({ block: rect.height > window.innerHeight ? "start" : "nearest" });
    }
    this.render();
  };

  Listing.prototype.anchor = function (n) {
    if (location.hash === "#L" + n) this.go(n, true);
    else location.hash = "#L" + n;  // the hashchange handler goes there
  };

  Listing.prototype.search = function (query) {
    this.query = query;
    this.matches = [];
    this.current = -1;
    if (query) {
      var needle = query.toLowerCase();
      var lines = this.lines;
      for (var i = 0; i < lines.length && this.matches.length < MAX_MATCHES; i++) {
        var hay = lines[i].toLowerCase();
        var at = hay.indexOf(needle);
        while (at >= 0 && this.matches.length < MAX_MATCHES) {
          this.matches.push([i, at]);
          at = hay.indexOf(needle, at + needle.length);
        }
      }
      // the first match from the line at the top of the view
      var from = this.first + OVERSCAN;
      this.current = 0;
      for (var k = 0; k < this.matches.length; k++) {
        if (this.matches[k][0] >= from) { this.current = k; break; }
      }
    }
    this.show();
  };

  Listing.prototype.step = function (direction) {
    if (!this.matches.length) return;
    var n = this.matches.length;
    this.current = (this.current + direction + n) % n;
    this.show();
  };

  Listing.prototype.show = function () {
    var n = this.matches.length;
    if (!this.query) this.count.textContent = "";
    else if (!n) this.count.textContent = "no match";
    else {
      this.count.textContent = (this.current + 1) + " of " + n + (n >= MAX_MATCHES ? "+" : "");
    }
    if (n && this.current >= 0) {
      var line = this.matches[this.current][0] + 1;
      var row = this.rows.querySelector("#L" + line);
      var box = this.box.getBoundingClientRect();
      var visible = row && row.getBoundingClientRect().top >= box.top &&
        row.getBoundingClientRect().bottom <= box.bottom;
      if (!visible) this.go(line, false);
    }
    this.render();
  };

  function start() {
    var root = document.querySelector(".listing");
    if (!root || !window.NcHighlight) return;
    var listing = new Listing(root);
    window.opendncListing = listing;
    var target = Listing.hashLine() || parseInt(root.dataset.line || "0", 10);
    var src = root.dataset.src;
    if (!src) {
      // too large to fetch whole: the server's window, with its row marked
      var row = target && document.getElementById("L" + target);
      if (row) {
        row.classList.add("hl");
        row.scrollIntoView({ block: "center" });
      }
      return;
    }
    listing.load(src).then(function () {
      // the hash as it is now: a problem's link clicked while the text was on its way
      // changed it, and go() could not scroll to a line that had not come yet
      var now = Listing.hashLine() || target;
      if (now) listing.go(now, true);
    }).catch(function (error) {
      var note = document.createElement("p");
      note.className = "muted";
      note.textContent = String(error.message || error) + "; the lines above are a window of the text.";
      root.appendChild(note);
    });
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();
