// The 3D scene's player (balance_opt/report/scene.py inlines it in scene.html): runs the
// meshcat commands of the scene's data (S), then drives the animation
// from the plan and rotation selectors, the play button, the time slider and the URL's
// fragment (#method=optimal&t=5&magnify=10&play).
const S = SCENE_DATA;
const pane = document.getElementById('scene-pane');
const viewer = new MeshCat.Viewer(pane);
const fit = viewer.set_3d_pane_size.bind(viewer);  // the viewer takes the window's height
viewer.set_3d_pane_size = function () { fit(pane.clientWidth, pane.clientHeight); };
viewer.set_3d_pane_size();
function run(b64) { const s = atob(b64), a = new Uint8Array(s.length);
  for (let i = 0; i < s.length; i++) a[i] = s.charCodeAt(i);
  viewer.handle_command_bytearray(a); }
S.setup.forEach(run);
// a mesh that several links carry is sent once: the others take its geometry
function drawnAt(path) { return viewer.scene_tree.find(path.split('/').filter(Boolean)
  .concat(['<object>'])).object; }
S.shared.forEach(function (s) { drawnAt(s[0]).geometry = drawnAt(s[1]).geometry; });
const sel = document.getElementById('scene-method'), mag = document.getElementById('scene-mag');
const sl = document.getElementById('scene-t'), btn = document.getElementById('scene-play');
const lab = document.getElementById('scene-label'), note = document.getElementById('scene-note');
const anim = viewer.animator;
function method() { return S.methods[sel.value]; }
// the key in force at t: the last one at or before it
function keyAt(times, t) { let k = 0;
  while (k + 1 < times.length && times[k + 1] <= t + 1e-9) k++;
  return k; }
function show(t) { const m = method(), a = m.angle[keyAt(m.angle_t, t)];
  let s = 't = ' + (m.t0 + t).toFixed(2) + ' s of ' + (m.t0 + m.duration).toFixed(2) +
    ' s; base rotation from the start ' + a.toPrecision(3) + ' rad (' +
    (a * 180 / Math.PI).toFixed(2) + ' deg)';
  if (S.target) s += (m.t0 + t >= S.target.time ? '; target captured' : '; target free') +
    ' (capture at ' + S.target.time + ' s)';
  const near = m.near ? m.near[keyAt(m.near.map(function (n) { return n[0]; }), t)][1] : '';
  if (near) s += '; ' + near;
  lab.textContent = s; sl.value = t; }
// the viewer's player applies only running actions: hold them paused at the time shown
function seek(t) { anim.playing = false; anim.clock.stop();
  anim.actions.forEach(function (a) { a.play(); a.paused = true; a.time = t; });
  anim.mixer.update(0); viewer.set_dirty(); show(t); btn.textContent = 'play'; }
function load(t) { run(S.animations[sel.value + '|' + mag.value]);
  sl.max = method().duration; seek(Math.min(t, method().duration));
  const f = +mag.value;
  note.textContent = f === 1 ? 'Base rotation: as planned.' :
    'Base rotation magnified ' + f + ' times (its rotation from the start), so that a drift ' +
    'of a few degrees shows; the arms move as planned relative to the base.'; }
sel.onchange = function () { load(+sl.value); }; mag.onchange = sel.onchange;
sl.oninput = function () { seek(+sl.value); };
btn.onclick = function () { if (anim.playing) { seek(+sl.value); return; }
  const t = +sl.value >= method().duration - 1e-6 ? 0 : +sl.value;
  seek(t); anim.actions.forEach(function (a) { a.paused = false; });
  anim.clock.start(); anim.playing = true; btn.textContent = 'pause'; };
(function tick() {
  if (anim.playing) show(anim.actions.reduce(function (m, a) { return Math.max(m, a.time); }, 0));
  else if (btn.textContent === 'pause') btn.textContent = 'play';
  requestAnimationFrame(tick); })();
const h = new URLSearchParams(location.hash.slice(1));
if (h.has('method') && S.methods[h.get('method')]) sel.value = h.get('method');
if (h.has('magnify') && S.factors.indexOf(+h.get('magnify')) >= 0) mag.value = h.get('magnify');
load(h.has('t') ? +h.get('t') : 0);
if (h.has('play')) btn.onclick();
