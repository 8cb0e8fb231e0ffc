// opendnc program editor (docs/dashboard.md#program-check-and-editor): a plain <textarea> that holds the text
// and is submitted with the form, over a highlighted copy of the lines in view. Only the
// visible lines are highlighted and numbered, so a program of 20,000 lines scrolls as
// smoothly as one of 20. No library, no build step: this file is shipped as it is.
"use strict";

// -- highlighting ------------------------------------------------------------------------
// A token is [class, text]; the classes are styled in workbench.css (.hl-*).

const GCODE_WORDS = new Set([
  "IF", "GOTO", "THEN", "WHILE", "DO", "END", "EQ", "NE", "GT", "LT", "GE", "LE", "AND",
  "OR", "XOR", "MOD", "SIN", "COS", "TAN", "ASIN", "ACOS", "ATAN", "SQRT", "ABS", "BIN",
  "BCD", "ROUND", "FIX", "FUP", "LN", "EXP", "POPEN", "PCLOS", "DPRNT",
]);
const ADDRESS_CLASS = {
  G: "g", M: "m", T: "t", S: "sf", F: "sf", H: "hd", D: "hd", N: "n", O: "o", P: "p",
  L: "p", Q: "p", E: "p",
};
const AXES = "XYZABCUVWIJKR";

function gcodeTokens(line) {
  const out = [];
  let i = 0;
  const n = line.length;
  while (i < n) {
    const ch = line[i];
    if (ch === "(") { // a comment to its closing parenthesis (or the line's end)
      const end = line.indexOf(")", i);
      const stop = end < 0 ? n : end + 1;
      out.push(["c", line.slice(i, stop)]);
      i = stop;
    } else if (ch === ";") {
      out.push(["c", line.slice(i)]);
      i = n;
    } else if (ch === "#") { // a macro variable: #100, #[#1+2]
      let j = i + 1;
      if (line[j] === "[") {
        let depth = 0;
        for (; j < n; j++) {
          if (line[j] === "[") depth++;
          else if (line[j] === "]" && --depth === 0) { j++; break; }
        }
      } else {
        while (j < n && /[0-9]/.test(line[j])) j++;
      }
      out.push(["v", line.slice(i, j)]);
      i = j;
    } else if (/[A-Za-z]/.test(ch)) {
      let j = i;
      while (j < n && /[A-Za-z]/.test(line[j])) j++;
      const word = line.slice(i, j).toUpperCase();
      if (j - i > 1 && GCODE_WORDS.has(word)) {
        out.push(["k", line.slice(i, j)]);
        i = j;
        continue;
      }
      // an address: one letter and its number (G01, X-1.5, F.2)
      j = i + 1;
      while (j < n && /[ \t]/.test(line[j]) && /[-+0-9.]/.test(line[j + 1] || "")) j++;
      if (line[j] === "-" || line[j] === "+") j++;
      while (j < n && /[0-9.]/.test(line[j])) j++;
      const letter = ch.toUpperCase();
      const cls = ADDRESS_CLASS[letter] || (AXES.includes(letter) ? "ax" : "w");
      out.push([cls, line.slice(i, j)]);
      i = j;
    } else if (ch === "%" || ch === "/") {
      out.push(["o", ch]);
      i++;
    } else {
      let j = i + 1;
      while (j < n && !/[A-Za-z#(;%]/.test(line[j])) j++;
      out.push(["", line.slice(i, j)]);
      i = j;
    }
  }
  return out;
}

const KLARTEXT_WORDS = new Set([
  "BEGIN", "END", "PGM", "MM", "INCH", "BLK", "FORM", "TOOL", "CALL", "DEF", "L", "C",
  "CC", "CR", "CT", "RND", "CHF", "LP", "CP", "LBL", "REP", "FN", "CYCL", "PAT", "STOP",
  "FMAX", "FAUTO", "FZ", "FU", "R0", "RL", "RR", "DR+", "DR-", "SQ", "IF", "GOTO", "EQU",
  "NE", "GT", "LT", "PLANE", "SPATIAL", "RESET", "APPR", "DEP", "LN", "LT", "LCT", "CT",
  "SEL", "TABLE", "DATUM", "PRESET", "TCH", "PROBE", "M", "Q",
]);

function klartextTokens(line) {
  const out = [];
  const lead = /^(\s*)(\d+)/.exec(line); // the block number
  let i = 0;
  if (lead) {
    if (lead[1]) out.push(["", lead[1]]);
    out.push(["n", lead[2]]);
    i = lead[0].length;
  }
  const n = line.length;
  while (i < n) {
    const rest = line.slice(i);
    let m;
    if (rest[0] === ";") {
      out.push(["c", rest]);
      break;
    } else if ((m = /^Q[RLS]?\d+/i.exec(rest))) {
      out.push(["v", m[0]]);
    } else if ((m = /^I?(?:P[AR]|[XYZABCUVW])[-+]?(?:[0-9.]+|Q[RLS]?\d+)?(?![A-Z])/i.exec(rest))) {
      out.push(["ax", m[0]]);
    } else if ((m = /^R[0LR](?![0-9A-Z])/i.exec(rest))) { // radius compensation
      out.push(["k", m[0]]);
    } else if ((m = /^(?:D[LR]|R)[-+]?[0-9.]+/i.exec(rest))) {
      out.push(["hd", m[0]]);
    } else if ((m = /^(?:F|S)[-+]?[0-9.]+/i.exec(rest))) {
      out.push(["sf", m[0]]);
    } else if ((m = /^M\d+/i.exec(rest))) {
      out.push(["m", m[0]]);
    } else if ((m = /^[A-Z][A-Z0-9_]*[+-]?/i.exec(rest))) {
      const word = m[0].toUpperCase();
      out.push([KLARTEXT_WORDS.has(word) || KLARTEXT_WORDS.has(word.replace(/[+-]$/, "")) ? "k" : "", m[0]]);
    } else if ((m = /^[^A-Za-z;]+/.exec(rest))) {
      out.push(["", m[0]]);
    } else {
      m = [rest[0]];
      out.push(["", m[0]]);
    }
    i += m[0].length;
  }
  return out;
}

function escapeHtml(text) {
  return text.replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
}

function highlightLine(line, language) {
  const tokens = language === "klartext" ? klartextTokens(line) : gcodeTokens(line);
  let html = "";
  for (const [cls, text] of tokens) {
    html += cls ? `<span class="hl-${cls}">${escapeHtml(text)}</span>` : escapeHtml(text);
  }
  return html;
}

// -- the editor ----------------------------------------------------------------------------

function setUpEditor(root) {
  const form = root.closest("form");
  const area = root.querySelector("textarea");
  const view = root.querySelector(".ed-view");
  const code = view.querySelector("code");
  const marks = root.querySelector(".ed-marks");
  const gutter = root.querySelector(".ed-gutter-lines");
  const status = document.getElementById("ed-status");
  const found = document.getElementById("ed-found");
  const find = document.getElementById("ed-find");
  const replace = document.getElementById("ed-replace");
  const matchCase = document.getElementById("ed-case");
  const gotoInput = document.getElementById("ed-goto");
  const language = root.dataset.language || "gcode";
  const original = area.value;

  let lines = area.value.split("\n");
  let hit = null; // [start, end] of the match found last
  let current = 0; // line of the caret (0-based)
  let queued = false;
  const metrics = { line: 20, char: 8, top: 0, left: 0 };

  function measure() {
    const style = getComputedStyle(area);
    metrics.line = parseFloat(style.lineHeight) || 20;
    metrics.top = parseFloat(style.paddingTop) || 0;
    metrics.left = parseFloat(style.paddingLeft) || 0;
    const probe = document.createElement("span");
    probe.textContent = "0".repeat(100);
    probe.style.font = style.font;
    probe.style.visibility = "hidden";
    probe.style.position = "absolute";
    probe.style.whiteSpace = "pre";
    document.body.appendChild(probe);
    metrics.char = probe.getBoundingClientRect().width / 100 || 8;
    probe.remove();
  }

  function needle() {
    return find.value;
  }

  function sameText(a, b) {
    return matchCase.checked ? a === b : a.toLowerCase() === b.toLowerCase();
  }

  function schedule() {
    if (queued) return;
    queued = true;
    requestAnimationFrame(() => { queued = false; draw(); });
  }

  // Draw the lines in view (and one more), their numbers, and the search marks on them.
  function draw() {
    const first = Math.max(0, Math.floor((area.scrollTop - metrics.top) / metrics.line));
    const count = Math.ceil(area.clientHeight / metrics.line) + 2;
    const last = Math.min(lines.length, first + count);
    let html = "";
    let numbers = "";
    for (let k = first; k < last; k++) {
      html += highlightLine(lines[k], language) + "\n";
      numbers += `<div${k === current ? ' class="cur"' : ""}>${k + 1}</div>`;
    }
    code.innerHTML = html;
    gutter.innerHTML = numbers;
    const y = metrics.top + first * metrics.line - area.scrollTop;
    code.style.transform = `translate(${metrics.left - area.scrollLeft}px, ${y}px)`;
    gutter.style.transform = `translateY(${y}px)`;
    drawMarks(first, last, y);
  }

  function drawMarks(first, last, y) {
    const text = needle();
    let boxes = "";
    if (text) {
      const wanted = matchCase.checked ? text : text.toLowerCase();
      let offset = 0;
      for (let k = 0; k < first; k++) offset += lines[k].length + 1;
      for (let k = first; k < last; k++) {
        const line = matchCase.checked ? lines[k] : lines[k].toLowerCase();
        let at = line.indexOf(wanted);
        while (at >= 0) {
          const isHit = hit && hit[0] === offset + at;
          const left = metrics.left + at * metrics.char - area.scrollLeft;
          const top = (k - first) * metrics.line + y;
          boxes += `<div class="ed-mark${isHit ? " hit" : ""}" style="left:${left}px;top:${top}px;width:${wanted.length * metrics.char}px;height:${metrics.line}px"></div>`;
          at = line.indexOf(wanted, at + Math.max(1, wanted.length));
        }
        offset += lines[k].length + 1;
      }
    }
    marks.innerHTML = boxes;
  }

  function lineOf(offset) {
    let line = 0;
    let at = area.value.indexOf("\n");
    while (at >= 0 && at < offset) {
      line++;
      at = area.value.indexOf("\n", at + 1);
    }
    return line;
  }

  function offsetOf(line) {
    let offset = 0;
    for (let k = 0; k < line && k < lines.length; k++) offset += lines[k].length + 1;
    return offset;
  }

  function reveal(line, column) {
    const top = metrics.top + line * metrics.line;
    if (top < area.scrollTop || top + metrics.line > area.scrollTop + area.clientHeight) {
      area.scrollTop = Math.max(0, top - area.clientHeight / 3);
    }
    const left = metrics.left + (column || 0) * metrics.char;
    if (left < area.scrollLeft || left > area.scrollLeft + area.clientWidth - 4 * metrics.char) {
      area.scrollLeft = Math.max(0, left - area.clientWidth / 2);
    }
  }

  function updateStatus() {
    const caret = area.selectionStart;
    current = lineOf(caret);
    const column = caret - offsetOf(current) + 1;
    const changed = area.value !== original ? " · changed" : "";
    status.textContent = `Line ${current + 1}, column ${column} · ${lines.length.toLocaleString("en")} lines${changed}`;
  }

  function select(start, end, focusText) {
    hit = [start, end];
    area.setSelectionRange(start, end);
    const line = lineOf(start);
    reveal(line, start - offsetOf(line));
    if (focusText) area.focus();
    updateStatus();
    schedule();
  }

  function findFrom(from) {
    const text = needle();
    if (!text) {
      found.textContent = "Nothing to find";
      return null;
    }
    const hay = matchCase.checked ? area.value : area.value.toLowerCase();
    const wanted = matchCase.checked ? text : text.toLowerCase();
    let at = hay.indexOf(wanted, from);
    let wrapped = false;
    if (at < 0) {
      at = hay.indexOf(wanted);
      wrapped = at >= 0;
    }
    if (at < 0) {
      hit = null;
      found.textContent = `“${text}” not found`;
      schedule();
      return null;
    }
    const line = lineOf(at) + 1;
    found.textContent = `Found on line ${line}${wrapped ? " (from the top)" : ""}`;
    return at;
  }

  function findNext() {
    const from = hit ? hit[0] + 1 : area.selectionEnd;
    const at = findFrom(from);
    if (at !== null) select(at, at + needle().length, false);
  }

  function changed() {
    lines = area.value.split("\n");
    updateStatus();
    schedule();
  }

  function replaceOne() {
    const text = needle();
    if (!text) return findNext();
    const start = hit ? hit[0] : -1;
    if (start < 0 || !sameText(area.value.slice(start, start + text.length), text)) {
      return findNext(); // nothing chosen yet: find first, replace on the next press
    }
    area.setRangeText(replace.value, start, start + text.length, "end");
    changed();
    const at = findFrom(start + replace.value.length);
    if (at !== null) select(at, at + text.length, false);
    else hit = null;
  }

  function replaceAll() {
    const text = needle();
    if (!text) return;
    const escaped = text.replace(/[.*+?^${}()|[\]\\]/g, "\\$&");
    const pattern = new RegExp(escaped, matchCase.checked ? "g" : "gi");
    let count = 0;
    const value = area.value.replace(pattern, () => { count++; return replace.value; });
    if (count) {
      const keep = area.scrollTop;
      area.value = value;
      area.scrollTop = keep;
      hit = null;
      changed();
    }
    found.textContent = `${count} replaced`;
  }

  function goToLine() {
    const wanted = parseInt(gotoInput.value, 10);
    if (!Number.isFinite(wanted) || wanted < 1) return;
    const line = Math.min(wanted, lines.length) - 1;
    const offset = offsetOf(line);
    hit = null;
    area.focus();
    area.setSelectionRange(offset, offset);
    area.scrollTop = Math.max(0, metrics.top + line * metrics.line - area.clientHeight / 3);
    area.scrollLeft = 0;
    found.textContent = `Line ${line + 1}`;
    updateStatus();
    schedule();
  }

  area.addEventListener("input", changed);
  area.addEventListener("scroll", schedule);
  area.addEventListener("keyup", () => { updateStatus(); schedule(); });
  area.addEventListener("click", () => { hit = null; updateStatus(); schedule(); });
  find.addEventListener("input", () => { hit = null; found.textContent = ""; schedule(); });
  matchCase.addEventListener("change", () => { hit = null; schedule(); });
  find.addEventListener("keydown", (e) => {
    if (e.key === "Enter") { e.preventDefault(); findNext(); }
  });
  replace.addEventListener("keydown", (e) => {
    if (e.key === "Enter") { e.preventDefault(); replaceOne(); }
  });
  gotoInput.addEventListener("keydown", (e) => {
    if (e.key === "Enter") { e.preventDefault(); goToLine(); }
  });
  document.getElementById("ed-next").addEventListener("click", findNext);
  document.getElementById("ed-replace-one").addEventListener("click", replaceOne);
  document.getElementById("ed-replace-all").addEventListener("click", replaceAll);
  document.getElementById("ed-go").addEventListener("click", goToLine);
  form.addEventListener("keydown", (e) => {
    if (!(e.ctrlKey || e.metaKey)) return;
    const key = e.key.toLowerCase();
    if (key === "f" || key === "h") { e.preventDefault(); find.focus(); find.select(); }
    else if (key === "g" || key === "l") { e.preventDefault(); gotoInput.focus(); gotoInput.select(); }
  });
  window.addEventListener("resize", () => { measure(); schedule(); });
  // A browser may restore a scrolled textarea on reload: draw what it shows.
  measure();
  const wanted = /^#L(\d+)$/.exec(location.hash);
  if (wanted) {
    gotoInput.value = wanted[1];
    goToLine();
  }
  updateStatus();
  draw();
  root.classList.add("ready");
}

document.addEventListener("DOMContentLoaded", () => {
  for (const root of document.querySelectorAll(".ed")) setUpEditor(root);
});
