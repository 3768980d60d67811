// Typesets the maths that pymdownx.arithmatex (generic mode) leaves in the page:
// <span class="arithmatex">\(...\)</span> inline, <div class="arithmatex">\[...\]</div> display.
// KaTeX itself is vendored under assets/katex/ (served with the site, no network needed).
(function () {
  function typeset(root) {
    if (typeof katex === "undefined") return;
    root.querySelectorAll(".arithmatex").forEach(function (el) {
      if (el.dataset.katex) return;               // already typeset
      var tex = el.textContent.trim();
      var display = el.tagName === "DIV";
      var m;
      if ((m = tex.match(/^\\\(([\s\S]*)\\\)$/))) { tex = m[1]; display = false; }
      else if ((m = tex.match(/^\\\[([\s\S]*)\\\]$/))) { tex = m[1]; display = true; }
      try {
        katex.render(tex, el, { displayMode: display, throwOnError: false, strict: "ignore" });
        el.dataset.katex = "1";
      } catch (e) {
        console.error("katex:", e);
      }
    });
  }
  if (typeof document$ !== "undefined") {
    document$.subscribe(function () { typeset(document.body); });   // Material's page-load observable
  } else {
    document.addEventListener("DOMContentLoaded", function () { typeset(document.body); });
  }
})();
