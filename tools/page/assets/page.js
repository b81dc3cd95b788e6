// The operator page: renders each status snapshot that /events pushes (no reload). Every value
// from nccompd goes into the page as text (textContent), never as markup.
'use strict';

const $ = (id) => document.getElementById(id);

function el(tag, text, cls) {
  const e = document.createElement(tag);
  if (text !== undefined && text !== null) e.textContent = String(text);
  if (cls) e.className = cls;
  return e;
}

function fixed(v, digits) {
  return typeof v === 'number' ? v.toFixed(digits) : (v === null || v === undefined ? '—' : v);
}

function row(cells) {
  const tr = document.createElement('tr');
  for (const c of cells) {
    const td = el('td', c.text, c.cls);
    if (c.name) td.dataset.name = c.name;
    if (c.title) td.title = c.title;
    tr.appendChild(td);
  }
  return tr;
}

function fillBody(table, rows) {
  const body = table.tBodies[0];
  body.replaceChildren(...rows);
}

function limitsText(r) {
  const parts = [];
  if (typeof r.max_abs_um === 'number') parts.push('|x| ≤ ' + r.max_abs_um + ' µm');
  // A flag is written as asked: only max_abs_um applies to it.
  if (r.kind !== 'flag') {
    if (typeof r.max_step_um === 'number') parts.push('step ≤ ' + r.max_step_um + ' µm');
    if (typeof r.max_rate_um_per_s === 'number') parts.push('rate ≤ ' + r.max_rate_um_per_s + ' µm/s');
  }
  return parts.length ? parts.join(', ') : 'not reported';
}

function renderRegisters(regs) {
  fillBody($('registers'), regs.map((r) => {
    let state = 'steady';
    let cls = '';
    if (r.hold) { state = 'held: ' + r.hold; cls = 'state-hold'; }
    else if (r.slewing) { state = 'slewing'; cls = 'state-slewing'; }
    if (r.awaiting_nc) state += ' (waiting for the NC)';
    const tr = row([
      { text: r.index, cls: 'num' },
      { text: r.name },
      { text: fixed(r.output_um, 3), cls: 'num output' },
      { text: fixed(r.target_um, 3), cls: 'num target' },
      { text: limitsText(r), cls: 'limits' },
      { text: state, cls: 'state ' + cls },
    ]);
    tr.dataset.register = r.name;
    return tr;
  }));
}

function renderLoop(loop) {
  const l = loop.latency_us || {};
  const items = [
    ['rate', fixed(loop.rate_hz, 1) + ' Hz configured, ' + fixed(loop.measured_rate_hz, 1) + ' Hz measured', 'rate'],
    ['cycles', loop.cycles, 'cycles'],
    ['overruns', loop.overruns + ' (' + loop.missed_deadlines + ' deadlines missed)', 'overruns'],
    ['wake-up latency', 'p50 ' + fixed(l.p50, 0) + ' µs, p99 ' + fixed(l.p99, 0) + ' µs, p99.9 ' +
      fixed(l.p99_9, 0) + ' µs, max ' + fixed(l.max, 0) + ' µs', 'latency'],
    ['longest cycle', fixed(loop.max_cycle_us, 0) + ' µs', 'max_cycle'],
  ];
  fillBody($('loop'), items.map(([k, v, name]) => row([{ text: k }, { text: v, name: name }])));
}

function moduleStatus(status, name) {
  const m = (status.modules || []).find((x) => x.name === name);
  return m ? m.status : null;
}

function renderModules(status) {
  const cards = (status.modules || []).map((m) => {
    const box = el('div');
    box.dataset.module = m.name;
    box.appendChild(el('h3', m.name));
    const t = el('table', null, 'kv');
    t.appendChild(document.createElement('tbody'));
    fillBody(t, Object.entries(m.status).map(([k, v]) =>
      row([{ text: k }, { text: v === null ? 'not known yet' : v, cls: 'num', name: k }])));
    box.appendChild(t);
    return box;
  });
  $('modules').replaceChildren(...cards);
  const creep = moduleStatus(status, 'creep');
  if (!creep) {
    $('creeps').textContent = 'no creep module';
  } else {
    $('creeps').textContent = creep.creeps_in_progress + ' in progress, ' +
      fixed(creep.creep_remaining_um, 3) + ' µm still to creep in (wear in force ' +
      fixed(creep.wear_in_force_um, 3) + ' µm, mode ' + creep.mode + ')';
  }
  const latched = $('latched');
  if (creep && creep.halted === 1) {
    latched.textContent = 'HALTED: latched alarm ' + creep.latched_alarm +
      ' — nothing is applied until acknowledged or the tool is changed';
    latched.className = 'latched on';
  } else {
    latched.textContent = 'nothing latched';
    latched.className = 'latched';
  }
}

function renderAlarms(alarms) {
  const items = alarms.slice().reverse().map((a) => {
    const li = el('li', null, 'sev-' + a.severity);
    li.dataset.code = a.code;
    li.textContent = a.name + ' (code ' + a.code + ', ' + a.severity + ') subject ' + a.subject +
      ', value ' + a.value + ', at ' + fixed(a.time_s, 3) + ' s (daemon clock)';
    return li;
  });
  if (!items.length) items.push(el('li', 'none', 'none'));
  $('alarms').replaceChildren(...items);
}

function renderBuses(buses) {
  fillBody($('buses'), buses.map((b) => row([
    { text: b.name }, { text: b.state, cls: b.state === 'up' ? '' : 'state-hold' },
    { text: b.alarm ? 'ALARM' : 'no', cls: b.alarm ? 'state-hold' : '' },
    { text: b.frames_rx, cls: 'num' }, { text: b.frames_tx, cls: 'num' },
    { text: b.events_decoded, cls: 'num' }, { text: b.offsets_written, cls: 'num' },
    { text: b.offsets_failed, cls: 'num' }, { text: b.reconnects, cls: 'num' },
  ])));
}

// A model is named by its file's name and its hash (what identifies it); the whole path, the
// machine's own business, is the row's tooltip (and in `nccomp model status`).
function fileName(path) {
  return path ? path.slice(path.lastIndexOf('/') + 1) : path;
}

function modelText(r) {
  if (!r || !r.file) return 'none';
  return fileName(r.file) + ' (hash ' + (r.hash || 'unknown') + ')' +
    (r.since_utc ? ', live since ' + r.since_utc : '');
}

function scoreText(s) {
  if (!s || !s.parts) return 'no part scored yet';
  return s.parts + ' parts, mean squared error ' + fixed(s.mse_um2, 4) + ' µm²';
}

// What the model buttons may do now (set by renderModel, read by the dialog).
let modelState = { promote: false, rollback: false, live: 'none', candidate: 'none', previous: 'none' };

function renderModel(st) {
  const m = st.model;
  const sh = st.shadow;
  $('model-card').hidden = !m && !sh;
  if (!m && !sh) return;
  const items = [];
  if (m) {
    items.push(['live model', modelText(m.live), 'live', m.live && m.live.file]);
    items.push(['kept for rollback', modelText(m.previous), 'previous', m.previous && m.previous.file]);
  }
  let announced = false;
  if (sh) {
    announced = sh.phase === 'announced' && sh.promote === 'operator';
    items.push(['live model\'s score', scoreText(sh.live), 'live_score']);
    const other = sh.phase === 'watch' ? 'model the promotion replaced (watched)' : 'candidate in shadow';
    items.push([other, sh.phase === 'none' ? 'none' : fileName(sh.other.file), 'other',
      sh.phase === 'none' ? '' : sh.other.file]);
    if (sh.phase !== 'none') {
      items.push([sh.phase === 'watch' ? 'its score' : 'candidate\'s score', scoreText(sh.other), 'other_score']);
      items.push(['paired parts', sh.paired_parts + ': other better on ' + sh.other_better +
        ', live better on ' + sh.live_better + ', ties ' + sh.ties + ', p = ' +
        fixed(sh.p_value, 4), 'paired']);
    }
    const phases = {
      none: 'no candidate', candidate: 'waiting: scoring the candidate',
      announced: 'announced: the candidate is better, Promote makes it live',
      watch: 'promoted: watching for a demotion',
    };
    items.push(['rule', (phases[sh.phase] || sh.phase) + ' (promote: ' + sh.promote + ', ' +
      sh.decisions + ' decision(s))', 'phase']);
  }
  const h = st.handover || {};
  items.push(['handovers', h.handovers + ' (registers rebased ' + h.rebased + ', not absorbed ' +
    h.unabsorbed + '); last: largest trim change ' + fixed(h.last_trim_change_um, 3) + ' µm, ' +
    fixed(h.last_unabsorbed_um, 3) + ' µm through the limiter', 'handovers']);
  fillBody($('model'), items.map(([k, v, name, title]) =>
    row([{ text: k }, { text: v, name: name, title: title }])));
  modelState = {
    promote: announced,
    rollback: !!(m && m.previous && m.previous.file),
    live: m ? modelText(m.live) : 'the live model',
    candidate: sh && sh.phase !== 'none' ? fileName(sh.other.file) : 'none',
    previous: m ? modelText(m.previous) : 'the model kept for rollback',
  };
  $('promote').disabled = !actionsAllowed || !modelState.promote;
  $('promote').title = modelState.promote ? '' :
    'enabled when the rule announced a better candidate (promote = "operator")';
  $('rollback').disabled = !actionsAllowed || !modelState.rollback;
  $('rollback').title = modelState.rollback ? '' : 'no model kept for rollback';
}

let reportVersion = null;

async function loadReport() {
  const r = await fetch('/api/report');
  const rep = await r.json();
  const card = $('report-card');
  card.hidden = !rep.configured;
  if (!rep.configured) return;
  const s = rep.summary || {};
  $('report-meta').textContent = rep.error ? rep.error :
    rep.dir + ', written ' + rep.written_utc + ': declared model RMS ' +
    fixed(s.declared_rms_um, 3) + ' µm, final ' + fixed(s.final_rms_um, 3) +
    ' µm, noise floor ' + fixed(s.noise_floor_um, 3) + ' µm';
  fillBody($('report-effects'), (s.effects || []).map((e) => row([
    { text: e.name }, { text: e.column }, { text: e.form },
    { text: fixed(e.rms_before_um, 3), cls: 'num' }, { text: fixed(e.rms_after_um, 3), cls: 'num' },
    { text: fixed(e.heldout_rms_after_um, 3), cls: 'num' },
    { text: typeof e.p_value === 'number' ? e.p_value.toExponential(2) : e.p_value, cls: 'num' },
  ])));
  $('report-plots').replaceChildren(...(rep.plots || []).map((name) => {
    const img = el('img');
    img.src = '/report/plots/' + encodeURIComponent(name) + '?v=' + reportVersion;
    img.alt = name;
    return img;
  }));
}

let actionsAllowed = false;

function render(snap) {
  $('updated').textContent = snap.time_utc;
  const page = snap.page || {};
  actionsAllowed = !!page.actions;
  $('ack').disabled = !actionsAllowed;
  $('ack').title = actionsAllowed ? '' : 'actions are off on this page (listening beyond this host)';
  $('ack-who').textContent = 'Allowed: root and members of group ' + page.admin_group +
    ' (the user running this browser). nccomp-page and nccompd log who acknowledged.';
  $('model-who').textContent = 'Allowed: root and members of group ' + page.admin_group +
    ' (the user running this browser). nccomp-page and nccompd log who changed the model.';
  $('page-counters').textContent = 'nccomp-page: ' + page.actions_done + ' action(s) done, ' +
    page.actions_refused + ' refused, ' + page.bad_requests + ' bad request(s); actions: ' +
    'root and group ' + page.admin_group;
  if (page.report && page.report_version !== reportVersion) {
    reportVersion = page.report_version;
    loadReport().catch((e) => { $('report-meta').textContent = 'report: ' + e; });
  }
  const banner = $('banner');
  if (!snap.ok) {
    banner.hidden = false;
    banner.textContent = 'nccompd does not answer: ' + snap.error;
    $('conn').textContent = 'daemon down';
    $('conn').className = 'badge down';
    return;
  }
  const st = snap.status;
  banner.hidden = !(st.daemon.hold || st.daemon.dry_run);
  if (st.daemon.hold) {
    banner.textContent = 'HOLD: offsets are held, nothing is written to the NC' +
      (st.daemon.state_problem ? ': ' + st.daemon.state_problem : '');
  } else if (st.daemon.dry_run) {
    banner.textContent = 'DRY RUN: nothing is written to the NC';
  }
  $('conn').textContent = 'live';
  $('conn').className = 'badge live';
  $('daemon').textContent = 'nccompd pid ' + st.daemon.pid + ', config ' + st.daemon.config +
    ' (generation ' + st.daemon.config_generation + ')';
  renderRegisters(st.registers || []);
  renderLoop(st.loop || {});
  renderModules(st);
  renderAlarms(st.alarms || []);
  renderBuses(st.buses || []);
  renderModel(st);
  document.body.dataset.cycles = st.loop ? st.loop.cycles : '';
}

function connect() {
  const source = new EventSource('/events');
  source.onmessage = (m) => {
    try {
      render(JSON.parse(m.data));
    } catch (e) {
      $('banner').hidden = false;
      $('banner').textContent = 'cannot show the status: ' + e;
    }
  };
  source.onerror = () => {
    $('conn').textContent = 'reconnecting';
    $('conn').className = 'badge down';
  };
}

// The daemon's answer names models by their whole path: the line shows their file names (as
// the Model card does), its tooltip the answer as given.
function shortPaths(text) {
  return text.replace(/(^|[\s(:])(\/[^\s()]+)/g, (m, before, path) => before + fileName(path));
}

async function sendAction(action, out) {
  out.className = 'result';
  out.textContent = 'sending…';
  out.title = '';
  try {
    const r = await fetch('/api/action', {
      method: 'POST',
      headers: { 'Content-Type': 'application/json' },
      body: JSON.stringify({ action: action, confirmed: true }),
    });
    const body = await r.json();
    if (r.ok) {
      out.textContent = shortPaths(body.answer);
      out.title = body.answer;
    } else {
      out.className = 'result bad';
      out.textContent = 'refused (HTTP ' + r.status + '): ' + body.error;
    }
  } catch (e) {
    out.className = 'result bad';
    out.textContent = 'no answer from the page: ' + e;
  }
}

document.addEventListener('DOMContentLoaded', () => {
  const dialog = $('ack-dialog');
  $('ack').addEventListener('click', () => {
    if (!actionsAllowed) return;
    dialog.returnValue = '';
    dialog.showModal();
  });
  dialog.addEventListener('close', () => {
    if (dialog.returnValue === 'confirm') sendAction('acknowledge', $('ack-result'));
  });
  const modelDialog = $('model-dialog');
  let modelAction = '';
  const ask = (action) => {
    if (!actionsAllowed) return;
    modelAction = action;
    if (action === 'model_promote') {
      $('model-dialog-title').textContent = 'Promote the candidate?';
      $('model-dialog-text').textContent = 'The candidate ' + modelState.candidate +
        ' becomes the live model: every offset it computes is handed over through the limiter. ' +
        'The live model ' + modelState.live + ' is kept for rollback and watched beside it.';
    } else {
      $('model-dialog-title').textContent = 'Roll back the live model?';
      $('model-dialog-text').textContent = 'The live model ' + modelState.live +
        ' is replaced by the model kept for rollback, ' + modelState.previous +
        '; the offsets change to what that model computes, through the limiter.';
    }
    modelDialog.returnValue = '';
    modelDialog.showModal();
  };
  $('promote').addEventListener('click', () => ask('model_promote'));
  $('rollback').addEventListener('click', () => ask('model_rollback'));
  modelDialog.addEventListener('close', () => {
    if (modelDialog.returnValue === 'confirm') sendAction(modelAction, $('model-result'));
  });
  connect();
});
