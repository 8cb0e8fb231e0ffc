// opendnc program editor (docs/dashboard.md#program-check-and-editor) on CodeMirror 6
// (window.CM: codemirror-*.min.js, built once from tools/editor-bundle). Ours here: the
// G-code / Klartext highlighting of the lines in view (nchighlight.js), the live check as
// lint marks in the gutter, opening at ?line=N with its message, and the save.
"use strict";
(function () {
  const CHECK_DELAY_MS = 500; // typing pauses this long before the text is checked
  const SLICE = 256 * 1024; // characters copied per task when the text is sent (no long task)
  const LONG_LINE = 4000; // longer lines are not highlighted (a CAM dump of one line)
  const READ_SLICE = 256 * 1024; // bytes made into lines per task when a program opens

  function pause() {
    return new Promise((resolve) => setTimeout(resolve, 0));
  }

  // The program's bytes as a CodeMirror document, a slice per task: 10 MB split into lines
  // and built in one go is a long task of its own. Each slice ends at a line break; the
  // lines of the slices after the first are joined on with one ("" as their first line).
  async function documentOf(CM, buffer) {
    const bytes = new Uint8Array(buffer);
    // NC programs are 7-bit text; latin1 shows a stray byte rather than failing
    const decoder = new TextDecoder("latin1");
    const breaks = /\r\n|\r|\n/;
    let doc = null;
    let carry = "";
    for (let at = 0; at < bytes.length; at += READ_SLICE) {
      const piece = carry + decoder.decode(bytes.subarray(at, at + READ_SLICE), { stream: true });
      const cut = piece.lastIndexOf("\n");
      if (cut < 0) {
        carry = piece;
        continue;
      }
      const lines = piece.slice(0, cut).split(breaks);
      carry = piece.slice(cut + 1);
      doc = doc ? doc.append(CM.Text.of(["", ...lines])) : CM.Text.of(lines);
      await pause();
    }
    const rest = (carry + decoder.decode()).split(breaks);
    return doc ? doc.append(CM.Text.of(["", ...rest])) : CM.Text.of(rest);
  }

  function el(id) {
    return document.getElementById(id);
  }

  // The text of a CodeMirror document (immutable, so it can be read across tasks) as a
  // Blob, a slice per task: a 10 MB program copied at once is a long task while typing.
  function blobOf(doc) {
    return new Promise((resolve) => {
      const parts = [];
      let pos = 0;
      function step() {
        const end = Math.min(doc.length, pos + SLICE);
        parts.push(new Blob([doc.sliceString(pos, end)]));
        pos = end;
        if (pos < doc.length) setTimeout(step, 0);
        else resolve(new Blob(parts, { type: "text/plain;charset=utf-8" }));
      }
      step();
    });
  }

  // -- highlighting: our tokens (nchighlight.js) as mark decorations on the lines in view
  function highlighter(CM, dialect) {
    const cache = new Map();
    function mark(cls) {
      let found = cache.get(cls);
      if (!found) cache.set(cls, (found = CM.Decoration.mark({ class: cls })));
      return found;
    }
    function build(view) {
      const builder = new CM.RangeSetBuilder();
      const doc = view.state.doc;
      let done = -1; // end of the last line drawn (visible ranges may share a line)
      for (const { from, to } of view.visibleRanges) {
        let pos = from;
        while (pos <= to) {
          const line = doc.lineAt(pos);
          if (line.from > done && line.length <= LONG_LINE) {
            let at = line.from;
            for (const [cls, text] of window.NcHighlight.tokens(line.text, dialect)) {
              if (cls && text) builder.add(at, at + text.length, mark(cls));
              at += text.length;
            }
          }
          done = line.to;
          pos = line.to + 1;
        }
      }
      return builder.finish();
    }
    return CM.ViewPlugin.fromClass(
      class {
        constructor(view) {
          this.decorations = build(view);
        }
        update(update) {
          if (update.docChanged || update.viewportChanged) this.decorations = build(update.view);
        }
      },
      { decorations: (plugin) => plugin.decorations }
    );
  }

  // -- the check's problems as CodeMirror diagnostics on ``doc``
  function diagnostics(doc, problems) {
    const out = [];
    for (const p of problems) {
      const n = Math.min(Math.max(1, p.line || 1), doc.lines);
      const line = doc.line(n);
      out.push({
        from: line.from,
        to: line.to,
        severity: p.severity === "error" ? "error" : "warning",
        message: p.message,
      });
    }
    return out;
  }

  function grouped(n) {
    // 100000 -> "100,000" (toLocaleString costs a millisecond a call: this runs a keystroke)
    return String(n).replace(/\B(?=(\d{3})+(?!\d))/g, ",");
  }

  function counted(n, word) {
    return `${grouped(n)} ${word}${n === 1 ? "" : "s"}`;
  }

  function setUp(CM, root) {
    const form = el("editor-form");
    const status = el("ed-status");
    const checkNote = el("ed-check");
    const lineNote = el("ed-line-msg");
    const csrf = form.elements.csrf.value;
    const dialect = root.dataset.language || "gcode";
    let problems = JSON.parse(el("ed-problems").textContent || "[]");
    let original = null; // the document as opened
    let view = null;

    // the live check: one request at a time, CHECK_DELAY_MS after the last change
    let timer = 0;
    let running = false;
    let again = false;
    let since = null; // the changes made while a check runs (its marks are mapped through them)
    let lasted = 0; // ms the last check took: a program that takes seconds is checked less often

    function schedule() {
      clearTimeout(timer);
      timer = setTimeout(check, Math.max(CHECK_DELAY_MS, lasted));
    }

    async function check() {
      if (running) {
        again = true;
        return;
      }
      running = true;
      again = false;
      const doc = view.state.doc;
      since = CM.ChangeSet.empty(doc.length);
      checkNote.textContent = "Checking…";
      const started = performance.now();
      try {
        const body = await blobOf(doc);
        const reply = await fetch(root.dataset.check, {
          method: "POST",
          body,
          credentials: "same-origin",
          headers: { "X-CSRF-Token": csrf, "Content-Type": "text/plain; charset=utf-8" },
        });
        if (!reply.ok) throw new Error(`the check answered ${reply.status}`);
        const found = await reply.json();
        problems = found.problems;
        const marks = diagnostics(doc, problems)
          .map((d) => ({ ...d, from: since.mapPos(d.from, 1), to: since.mapPos(d.to, 1) }))
          .filter((d) => d.from <= d.to);
        view.dispatch(CM.setDiagnostics(view.state, marks));
        checkNote.textContent = found.errors || found.warnings
          ? `Live check: ${counted(found.errors, "error")}, ${counted(found.warnings, "warning")}`
          : "Live check: no problems";
        checkNote.dataset.state = found.errors ? "errors" : found.warnings ? "warnings" : "ok";
      } catch (error) {
        checkNote.textContent = `Live check not done: ${error.message || error}`;
        checkNote.dataset.state = "failed";
      } finally {
        lasted = performance.now() - started;
        running = false;
        since = null;
        if (again) schedule();
      }
    }

    function showStatus(state) {
      const head = state.selection.main.head;
      const line = state.doc.lineAt(head);
      const changed = original !== null && state.doc !== original && !state.doc.eq(original);
      status.textContent =
        `Line ${line.number}, column ${head - line.from + 1} · ` +
        `${counted(state.doc.lines, "line")}${changed ? " · changed" : ""}`;
    }

    function messageAt(n) {
      const here = problems.filter((p) => p.line === n);
      if (!here.length) return `Line ${n}`;
      return `Line ${n}: ` + here.map((p) => `${p.severity}: ${p.message}`).join(" · ");
    }

    function goTo(n) {
      const doc = view.state.doc;
      const line = doc.line(Math.min(Math.max(1, n), doc.lines));
      view.dispatch({
        selection: { anchor: line.from },
        effects: CM.EditorView.scrollIntoView(line.from, { y: "center" }),
      });
      view.focus();
      lineNote.textContent = messageAt(line.number);
      lineNote.dataset.problem = String(problems.some((p) => p.line === line.number));
      lineNote.hidden = false;
    }

    function open(doc) {
      const state = CM.EditorState.create({
        doc,
        extensions: [
          CM.lineNumbers(),
          CM.lintGutter(),
          CM.highlightActiveLineGutter(),
          CM.highlightSpecialChars(),
          CM.history(),
          CM.drawSelection(),
          CM.highlightActiveLine(),
          CM.highlightSelectionMatches(),
          CM.search({ top: true }),
          highlighter(CM, dialect),
          CM.keymap.of([
            ...CM.defaultKeymap,
            ...CM.searchKeymap,
            ...CM.historyKeymap,
            ...CM.lintKeymap,
            { key: "Mod-l", run: CM.gotoLine, preventDefault: true },
          ]),
          CM.EditorView.contentAttributes.of({
            "aria-label": root.getAttribute("aria-label"),
            spellcheck: "false",
            autocapitalize: "off",
            autocorrect: "off",
          }),
          CM.EditorView.updateListener.of((update) => {
            if (update.docChanged) {
              if (since) since = since.compose(update.changes);
              lineNote.hidden = true;
              schedule();
            }
            if (update.docChanged || update.selectionSet) showStatus(update.state);
          }),
        ],
      });
      original = state.doc;
      root.textContent = "";
      view = new CM.EditorView({ state, parent: root });
      performance.mark("editor-view");
      window.opendncEditor = view; // the browser tests read the text through it
      view.dispatch(CM.setDiagnostics(view.state, diagnostics(view.state.doc, problems)));
      showStatus(view.state);
      el("ed-find").addEventListener("click", () => CM.openSearchPanel(view));
      el("ed-goto").addEventListener("click", () => CM.gotoLine(view));
      for (const id of ["ed-find", "ed-goto", "ed-submit"]) el(id).disabled = false;
      const wanted = parseInt(root.dataset.line || "0", 10);
      if (wanted > 0) goTo(wanted);
      root.classList.add("ready");
      performance.mark("editor-ready");
    }

    async function save(event) {
      event.preventDefault();
      const button = el("ed-submit");
      button.disabled = true;
      const data = new FormData(form);
      data.append("file", await blobOf(view.state.doc), root.dataset.name || "program");
      try {
        // htmx's conventions: 204 with HX-Location on success, an alert fragment on refusal
        const reply = await fetch(form.action, {
          method: "POST",
          body: data,
          credentials: "same-origin",
          headers: { "HX-Request": "true", "X-CSRF-Token": csrf },
        });
        const target = reply.headers.get("HX-Location");
        if (reply.ok && target) {
          location.assign(target);
          return;
        }
        el("alert").innerHTML = await reply.text();
      } catch (error) {
        el("alert").textContent = `Not saved: ${error.message || error}`;
      }
      button.disabled = false;
    }

    form.addEventListener("submit", save);
    fetch(root.dataset.src, { credentials: "same-origin" })
      .then((reply) => {
        if (!reply.ok) throw new Error(`the text could not be read (${reply.status})`);
        return reply.arrayBuffer();
      })
      .then((buffer) => {
        performance.mark("editor-fetched");
        return documentOf(CM, buffer);
      })
      .then((doc) => {
        performance.mark("editor-document");
        open(doc);
      })
      .catch((error) => {
        root.textContent = String(error.message || error);
      });
  }

  function start() {
    const root = el("ed");
    if (root && window.CM && window.NcHighlight) setUp(window.CM, root);
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();
