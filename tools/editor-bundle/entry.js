// The parts of CodeMirror 6 the program editor uses (static/nceditor.js), as one global:
// window.CM. Nothing of ours is in here; the editor's own code is a plain script beside it.
export { EditorState, EditorSelection, StateEffect, StateField, RangeSetBuilder, ChangeSet, Text } from "@codemirror/state";
export {
  EditorView, ViewPlugin, Decoration, keymap, lineNumbers, highlightActiveLine,
  highlightActiveLineGutter, drawSelection, highlightSpecialChars, scrollPastEnd,
} from "@codemirror/view";
export { defaultKeymap, history, historyKeymap, indentWithTab } from "@codemirror/commands";
export {
  search, searchKeymap, openSearchPanel, gotoLine, highlightSelectionMatches,
} from "@codemirror/search";
export { setDiagnostics, lintGutter, lintKeymap, forEachDiagnostic } from "@codemirror/lint";
