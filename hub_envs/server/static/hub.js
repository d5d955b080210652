// hub-envs embedded Hub: the copy buttons (data-copy="<id of the element whose text to copy>").
// Served from this server: the pages' Content-Security-Policy allows no inline script.
"use strict";
document.addEventListener("click", function (event) {
  var button = event.target.closest("[data-copy]");
  if (!button) return;
  var source = document.getElementById(button.getAttribute("data-copy"));
  if (!source) return;
  var text = source.textContent;
  function done(ok) {
    button.textContent = ok ? "Copied" : "Select and copy (Ctrl+C)";
    setTimeout(function () { button.textContent = "Copy"; }, 2000);
  }
  function fallback() {  // no Clipboard API (a page served over plain http to another host)
    var range = document.createRange();
    range.selectNodeContents(source);
    var selection = window.getSelection();
    selection.removeAllRanges();
    selection.addRange(range);
    var ok = false;
    try { ok = document.execCommand("copy"); } catch (e) { ok = false; }
    done(ok);
  }
  if (navigator.clipboard && window.isSecureContext) {
    navigator.clipboard.writeText(text).then(function () { done(true); }, fallback);
  } else {
    fallback();
  }
});
