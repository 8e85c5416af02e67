// Renders the maths that pymdownx.arithmatex (generic mode) leaves in elements of class "arithmatex":
// \( ... \) inline, \[ ... \] display. KaTeX and its auto-render extension are vendored under katex/,
// so the pages render offline. Material's document$ emits each page, instant navigation included.
(function () {
  "use strict";

  var options = {
    delimiters: [
      { left: "\\(", right: "\\)", display: false },
      { left: "\\[", right: "\\]", display: true },
    ],
  };

  function render(root) {
    root.querySelectorAll(".arithmatex").forEach(function (element) {
      renderMathInElement(element, options);
    });
  }

  if (typeof document$ !== "undefined") {
    document$.subscribe(function (doc) {
      render(doc.body || document.body);
    });
  } else if (document.readyState === "loading") {
    document.addEventListener("DOMContentLoaded", function () {
      render(document.body);
    });
  } else {
    render(document.body);
  }
})();
