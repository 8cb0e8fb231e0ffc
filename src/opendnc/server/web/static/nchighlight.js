/* opendnc: highlighting of one NC program line, G-code (Haas / Fanuc macro B, ISO) or
   Heidenhain conversational (Klartext). A plain script: window.NcHighlight.
     NcHighlight.tokens(text, dialect)      -> [[cssClass, text], ...] covering the line
     NcHighlight.html(text, dialect, marks) -> escaped HTML; marks: [[start, end], ...] get <mark>
   Classes: w-cmt comment, w-code G/M, w-ax axis/coordinate, w-tool T/H/D, w-feed F/S,
   w-blk N/O/block number, w-addr other address, w-num number, w-var #var / Q parameter,
   w-kw keyword, w-str text of a DPRNT or a label name. */
(function () {
  "use strict";

  var GCODE_KW = /^(IF|GOTO|WHILE|DO|END|THEN|EQ|NE|GT|LT|GE|LE|AND|OR|XOR|MOD|SIN|COS|TAN|ASIN|ACOS|ATAN|SQRT|ABS|ROUND|FIX|FUP|LN|EXP|BIN|BCD|POPEN|PCLOS|DPRNT|BPRNT)$/;
  var KT_KW = /^(BEGIN|END|PGM|MM|INCH|BLK|FORM|TOOL|CALL|DEF|CC|CR|CT|CP|LP|RND|CHF|LBL|REP|CYCL|FN|STOP|FMAX|FAUTO|FU|FZ|DL|DR|R0|RL|RR|PA|PR|IPA|IPR|PAT|DR\+|DR-|SQ|SIN|COS|TAN|ABS|INT|FRAC|SQRT|IF|GOTO|EQU|NE|GT|LT|PLANE|SPATIAL|RESET|SEL|TABLE|PATTERN|END|DECLARE|STRING|SYSREAD|ERROR|PRINT|ASIN|ACOS|ATAN|LN|LOG|EXP|NEG|ROUND)$/;
  var AXES = "XYZABCUVWIJKRQ";

  function push(out, cls, text) {
    if (!text) return;
    var last = out[out.length - 1];
    if (last && last[0] === cls) last[1] += text;
    else out.push([cls, text]);
  }

  function number(s, i) {
    // [+-]? digits [. digits] from i; the end index (i when none)
    var j = i;
    if (s[j] === "+" || s[j] === "-") j++;
    var k = j;
    while (k < s.length && ((s[k] >= "0" && s[k] <= "9") || s[k] === ".")) k++;
    return k > j ? k : i;
  }

  function letters(s, i) {
    var j = i;
    while (j < s.length && /[A-Za-z_]/.test(s[j])) j++;
    return j;
  }

  function gcode(s) {
    var out = [];
    var i = 0;
    while (i < s.length) {
      var c = s[i];
      var u = c.toUpperCase();
      if (c === "(") {
        var close = s.indexOf(")", i);
        var end = close < 0 ? s.length : close + 1;
        push(out, "w-cmt", s.slice(i, end));
        i = end;
      } else if (c === ";") {
        push(out, "w-cmt", s.slice(i));
        i = s.length;
      } else if (c === "#") {
        var j = i + 1;
        while (j < s.length && s[j] >= "0" && s[j] <= "9") j++;
        push(out, "w-var", s.slice(i, j));
        i = j;
      } else if (/[A-Za-z]/.test(c)) {
        var w = letters(s, i);
        var word = s.slice(i, w).toUpperCase();
        if (w - i > 1 && GCODE_KW.test(word)) {
          push(out, "w-kw", s.slice(i, w));
          i = w;
          if (word === "DPRNT" || word === "BPRNT") {
            var rb = s.indexOf("]", i);
            if (s[i] === "[" && rb > 0) {
              push(out, "", "[");
              push(out, "w-str", s.slice(i + 1, rb));
              push(out, "", "]");
              i = rb + 1;
            }
          }
          continue;
        }
        var n = number(s, i + 1);
        var cls = "w-addr";
        if (u === "G" || u === "M") cls = "w-code";
        else if (AXES.indexOf(u) >= 0) cls = "w-ax";
        else if (u === "T" || u === "H" || u === "D") cls = "w-tool";
        else if (u === "F" || u === "S") cls = "w-feed";
        else if (u === "N" || u === "O") cls = "w-blk";
        if (n > i + 1) {
          push(out, cls, c);
          push(out, cls === "w-blk" || cls === "w-code" ? cls : "w-num", s.slice(i + 1, n));
          i = n;
        } else {
          // a letter before an expression or a variable (X#101, G[#1]): the address only
          push(out, cls, c);
          i++;
        }
      } else if ((c >= "0" && c <= "9") || c === ".") {
        var m = number(s, i);
        push(out, "w-num", s.slice(i, m));
        i = m;
      } else {
        push(out, "", c);
        i++;
      }
    }
    return out;
  }

  function klartext(s) {
    var out = [];
    var i = 0;
    var lead = /^\s*\d+/.exec(s);
    if (lead) {
      push(out, "w-blk", lead[0]);
      i = lead[0].length;
    }
    while (i < s.length) {
      var c = s[i];
      var u = c.toUpperCase();
      if (c === ";") {
        push(out, "w-cmt", s.slice(i));
        break;
      }
      if (/[A-Za-z]/.test(c)) {
        var w = letters(s, i);
        var word = s.slice(i, w).toUpperCase();
        // Q parameters: Q12, QL3, QR4, QS5
        var q = /^(Q[LRS]?)(\d+)/i.exec(s.slice(i));
        if (q) {
          push(out, "w-var", q[0]);
          i += q[0].length;
          continue;
        }
        // a coordinate: X+10, IY-5, Z+Q3, CC's X, polar PR/PA handled as keywords
        var inc = u === "I" && w - i === 2 && AXES.indexOf(s[i + 1].toUpperCase()) >= 0;
        if ((w - i === 1 && AXES.indexOf(u) >= 0) || inc) {
          var after = w;
          var n = number(s, after);
          if (n > after) {
            push(out, "w-ax", s.slice(i, w));
            push(out, "w-num", s.slice(after, n));
            i = n;
            continue;
          }
          if (s[after] === "+" || s[after] === "-") {
            push(out, "w-ax", s.slice(i, after + 1));
            i = after + 1;
            continue;
          }
        }
        if (w - i === 1 && (u === "F" || u === "S" || u === "M")) {
          var m = number(s, w);
          if (m > w) {
            push(out, u === "M" ? "w-code" : "w-feed", c);
            push(out, u === "M" ? "w-code" : "w-num", s.slice(w, m));
            i = m;
            continue;
          }
        }
        if (word === "DR" && (s[w] === "+" || s[w] === "-")) {
          push(out, "w-kw", s.slice(i, w + 1));
          i = w + 1;
          continue;
        }
        if (KT_KW.test(word) || (w - i === 1 && (u === "L" || u === "C"))) {
          push(out, "w-kw", s.slice(i, w));
          i = w;
          if (word === "LBL" || word === "PGM") {
            var name = /^\s+("[^"]*"|\S+)/.exec(s.slice(i));
            if (name && !/^\d+$/.test(name[1])) {
              push(out, "", name[0].slice(0, name[0].length - name[1].length));
              push(out, "w-str", name[1]);
              i += name[0].length;
            }
          }
          continue;
        }
        push(out, "", s.slice(i, w));
        i = w;
      } else if ((c >= "0" && c <= "9") || c === "." || ((c === "+" || c === "-") && /[0-9.]/.test(s[i + 1] || ""))) {
        var k = number(s, i);
        if (k === i) k = i + 1;
        push(out, "w-num", s.slice(i, k));
        i = k;
      } else {
        push(out, "", c);
        i++;
      }
    }
    return out;
  }

  function tokens(text, dialect) {
    return dialect === "klartext" ? klartext(text) : gcode(text);
  }

  var ESC = { "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" };
  function escape(s) {
    return s.replace(/[&<>"]/g, function (ch) { return ESC[ch]; });
  }

  function html(text, dialect, marks) {
    var toks = tokens(text, dialect);
    var out = "";
    var pos = 0;
    var mi = 0;
    marks = marks || [];
    for (var t = 0; t < toks.length; t++) {
      var cls = toks[t][0];
      var part = toks[t][1];
      var start = pos;
      var end = pos + part.length;
      // split the token where marks begin or end
      var cuts = [start];
      for (var k = mi; k < marks.length && marks[k][0] < end; k++) {
        if (marks[k][0] > start) cuts.push(marks[k][0]);
        if (marks[k][1] > start && marks[k][1] < end) cuts.push(marks[k][1]);
      }
      cuts.push(end);
      cuts.sort(function (a, b) { return a - b; });
      for (var c = 0; c + 1 < cuts.length; c++) {
        var a = cuts[c];
        var b = cuts[c + 1];
        if (b <= a) continue;
        var piece = escape(text.slice(a, b));
        if (cls) piece = '<span class="' + cls + '">' + piece + "</span>";
        var marked = false;
        for (var j = mi; j < marks.length && marks[j][0] <= a; j++) {
          if (marks[j][1] > a) { marked = marks[j]; break; }
        }
        if (marked) piece = (marked[2] ? '<mark class="cur">' : "<mark>") + piece + "</mark>";
        out += piece;
      }
      while (mi < marks.length && marks[mi][1] <= end) mi++;
      pos = end;
    }
    return out;
  }

  window.NcHighlight = { tokens: tokens, html: html, escape: escape };
})();
