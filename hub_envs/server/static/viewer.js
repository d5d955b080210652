// hub-envs embedded Hub: the dataset viewer of one episode (episode.html). Fetches the episode's numbers
// (data.json), plots each feature on a canvas, and keeps the cameras (videos, or PNG frames), the scrubber and
// a marker on every plot at the same step. Served from this server: the pages' CSP allows no inline script.
"use strict";
(function () {
  var viewer = document.querySelector(".viewer");
  if (!viewer) return;
  var fps = parseFloat(viewer.getAttribute("data-fps")) || 30;
  var length = parseInt(viewer.getAttribute("data-length"), 10) || 0;
  var rev = viewer.getAttribute("data-rev");
  var framesUrl = viewer.getAttribute("data-frames");
  var scrubber = viewer.querySelector(".scrubber");
  var label = viewer.querySelector(".step-label");
  var playButton = viewer.querySelector(".play");
  var status = viewer.querySelector(".viewer-status");
  var videos = Array.prototype.slice.call(viewer.querySelectorAll("video.episode-video"));
  var images = Array.prototype.slice.call(viewer.querySelectorAll("img.episode-frame"));
  var plots = [];
  var step = 0;
  var playing = false;
  var timer = null;

  function clamp(s) { return Math.max(0, Math.min(length - 1, s)); }
  function from(video) { return parseFloat(video.getAttribute("data-from")) || 0; }
  function to(video) { return parseFloat(video.getAttribute("data-to")) || from(video) + length / fps; }

  // --- the step: scrubber, label, cameras, plot markers ---

  function setStep(s, source) {
    step = clamp(s);
    scrubber.value = String(step);
    label.textContent = "step " + step + " / " + (length - 1) + " · " + (step / fps).toFixed(2) + " s";
    viewer.setAttribute("data-step", String(step));
    if (source !== "video") {
      videos.forEach(function (v) { seek(v, step); });
    }
    images.forEach(function (img) {
      img.src = framesUrl + "/" + img.getAttribute("data-key") + "/" + step + ".png?rev=" + encodeURIComponent(rev);
      img.alt = img.getAttribute("data-key") + ", step " + step;
    });
    plots.forEach(drawMarker);
  }

  function seek(video, s) {
    // frame s of the episode is shown from from + s/fps: aim at its middle, inside the episode's span
    var t = Math.min(from(video) + (s + 0.5) / fps, to(video) - 0.001);
    if (Math.abs(video.currentTime - t) > 0.25 / fps) video.currentTime = t;
  }

  scrubber.addEventListener("input", function () {
    pause();
    setStep(parseInt(scrubber.value, 10) || 0, "scrubber");
  });

  // --- playing: the first video drives the step; without video, a timer at the dataset's fps ---

  function play() {
    if (length < 2) return;
    if (step >= length - 1) setStep(0, "play");
    playing = true;
    playButton.textContent = "Pause";
    viewer.setAttribute("data-playing", "true");
    if (videos.length) {
      videos.forEach(function (v) { v.play().catch(function () { pause(); }); });
      requestAnimationFrame(follow);
    } else {
      timer = setInterval(function () {
        if (step >= length - 1) { pause(); return; }
        setStep(step + 1, "play");
      }, 1000 / fps);
    }
  }

  function follow() {
    if (!playing) return;
    var v = videos[0];
    if (v.currentTime >= to(v) - 0.5 / fps || v.ended) {
      pause();
      setStep(length - 1, "video");
      return;
    }
    var s = clamp(Math.floor((v.currentTime - from(v)) * fps));
    if (s !== step) setStep(s, "video");
    requestAnimationFrame(follow);
  }

  function pause() {
    playing = false;
    playButton.textContent = "Play";
    viewer.setAttribute("data-playing", "false");
    videos.forEach(function (v) { v.pause(); });
    if (timer !== null) { clearInterval(timer); timer = null; }
  }

  playButton.addEventListener("click", function () { if (playing) pause(); else play(); });
  videos.forEach(function (v) {
    v.addEventListener("loadedmetadata", function () { seek(v, step); });
  });

  // --- the plots ---

  function colorOf(item) {
    var swatch = item.querySelector(".swatch");
    return swatch ? getComputedStyle(swatch).backgroundColor : "#0b5fcc";
  }

  function makePlot(canvas, series) {
    var figure = canvas.closest(".plot");
    var items = Array.prototype.slice.call(figure.querySelectorAll(".legend li"));
    var ratio = window.devicePixelRatio || 1;
    var width = canvas.clientWidth || 600;
    var height = canvas.clientHeight || 170;
    canvas.width = Math.round(width * ratio);
    canvas.height = Math.round(height * ratio);
    var lo = Infinity, hi = -Infinity, points = 0;
    series.values.forEach(function (dim) {
      dim.forEach(function (x) { if (x !== null) { lo = Math.min(lo, x); hi = Math.max(hi, x); points += 1; } });
    });
    if (!isFinite(lo)) { lo = 0; hi = 1; }
    if (hi === lo) { hi += 0.5; lo -= 0.5; }
    var pad = { left: 56, right: 10, top: 8, bottom: 20 };
    var plot = {
      canvas: canvas, series: series, items: items, ratio: ratio, width: width, height: height, pad: pad, lo: lo, hi: hi,
      x: function (s) { return pad.left + (length > 1 ? s / (length - 1) : 0) * (width - pad.left - pad.right); },
      y: function (v) { return pad.top + (1 - (v - lo) / (hi - lo)) * (height - pad.top - pad.bottom); },
      colors: items.map(colorOf),
    };
    plot.base = document.createElement("canvas");
    plot.base.width = canvas.width;
    plot.base.height = canvas.height;
    drawBase(plot);
    canvas.setAttribute("data-points", String(points));
    return plot;
  }

  function drawBase(p) {
    var ctx = p.base.getContext("2d");
    ctx.scale(p.ratio, p.ratio);
    ctx.fillStyle = "#fff";
    ctx.fillRect(0, 0, p.width, p.height);
    ctx.strokeStyle = "#d8dee4";
    ctx.lineWidth = 1;
    ctx.strokeRect(p.pad.left + 0.5, p.pad.top + 0.5, p.width - p.pad.left - p.pad.right, p.height - p.pad.top - p.pad.bottom);
    ctx.fillStyle = "#656d76";
    ctx.font = "11px system-ui, sans-serif";
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    ctx.fillText(format(p.hi), p.pad.left - 6, p.y(p.hi));
    ctx.fillText(format(p.lo), p.pad.left - 6, p.y(p.lo));
    if (p.lo < 0 && p.hi > 0) {
      ctx.strokeStyle = "#eaeef2";
      ctx.beginPath(); ctx.moveTo(p.pad.left, p.y(0)); ctx.lineTo(p.width - p.pad.right, p.y(0)); ctx.stroke();
      ctx.fillText("0", p.pad.left - 6, p.y(0));
    }
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    ctx.fillText("0", p.x(0), p.height - p.pad.bottom + 4);
    ctx.fillText(String(length - 1), p.x(length - 1), p.height - p.pad.bottom + 4);
    ctx.lineWidth = 1.5;
    p.series.values.forEach(function (dim, d) {
      ctx.strokeStyle = p.colors[d % p.colors.length] || "#0b5fcc";
      ctx.beginPath();
      var drawing = false;
      dim.forEach(function (v, s) {
        if (v === null) { drawing = false; return; }
        if (drawing) ctx.lineTo(p.x(s), p.y(v)); else ctx.moveTo(p.x(s), p.y(v));
        drawing = true;
      });
      ctx.stroke();
    });
  }

  function drawMarker(p) {
    var ctx = p.canvas.getContext("2d");
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.drawImage(p.base, 0, 0);
    ctx.scale(p.ratio, p.ratio);
    var x = p.x(step);
    ctx.strokeStyle = "#cf222e";
    ctx.lineWidth = 1;
    ctx.beginPath(); ctx.moveTo(x, p.pad.top); ctx.lineTo(x, p.height - p.pad.bottom); ctx.stroke();
    p.series.values.forEach(function (dim, d) {
      var v = dim[step];
      var value = p.items[d] && p.items[d].querySelector(".value");
      if (value) value.textContent = v === null || v === undefined ? "–" : format(v);
      if (v === null || v === undefined) return;
      ctx.fillStyle = p.colors[d % p.colors.length] || "#0b5fcc";
      ctx.beginPath(); ctx.arc(x, p.y(v), 3, 0, 2 * Math.PI); ctx.fill();
    });
    p.canvas.setAttribute("data-marker-step", String(step));
  }

  function format(v) {
    var a = Math.abs(v);
    if (a !== 0 && (a < 1e-3 || a >= 1e5)) return v.toExponential(2);
    return String(Math.round(v * 1000) / 1000);
  }

  // --- the data ---

  fetch(viewer.getAttribute("data-data"), { headers: { Accept: "application/json" } })
    .then(function (r) {
      if (!r.ok) throw new Error("the server answered " + r.status);
      return r.json();
    })
    .then(function (data) {
      var byKey = {};
      data.keys.forEach(function (s) { byKey[s.key] = s; });
      Array.prototype.slice.call(viewer.querySelectorAll(".plot canvas")).forEach(function (canvas) {
        var series = byKey[canvas.getAttribute("data-key")];
        if (series) plots.push(makePlot(canvas, series));
      });
      status.textContent = "";
      status.hidden = true;
      playButton.disabled = length < 2;
      setStep(0, "load");
      viewer.setAttribute("data-ready", "true");
    })
    .catch(function (err) {
      status.textContent = "The episode's data could not be loaded: " + err.message + ".";
      viewer.setAttribute("data-ready", "error");
    });
})();
