// MathJax configuration for pymdownx.arithmatex (generic mode). The MathJax library itself is not
// bundled: without it the formulas show as their TeX source, which stays readable.
window.MathJax = {
  tex: { inlineMath: [["\\(", "\\)"]], displayMath: [["\\[", "\\]"]], processEscapes: true },
  options: { ignoreHtmlClass: ".*|", processHtmlClass: "arithmatex" }
};
