// Typeset the math of every page with the vendored KaTeX (docs/assets/katex): the
// arithmatex spans of Markdown pages (\( \), \[ \]) and $ $ / $$ $$ in notebook cells.
function wfjaxTypeset() {
  renderMathInElement(document.body, {
    delimiters: [
      { left: "$$", right: "$$", display: true },
      { left: "\\[", right: "\\]", display: true },
      { left: "\\(", right: "\\)", display: false },
      { left: "$", right: "$", display: false },
    ],
    ignoredClasses: ["highlight", "highlight-ipynb", "jp-OutputArea-output"],
    throwOnError: false,
  });
}
if (typeof document$ !== "undefined") {
  document$.subscribe(wfjaxTypeset);   // Material's page-load observable (instant navigation)
} else {
  document.addEventListener("DOMContentLoaded", wfjaxTypeset);
}
