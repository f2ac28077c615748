#!/usr/bin/env node
// Records one two-bot episode on a running server (server.js): both first-person views are rendered
// in this process by prismarine-viewer (headless-gl on Xvfb) on every 20 Hz physics tick of each bot,
// together with that tick's raw action data, so frames and actions align by construction.
//
// Usage: node record.js '<json config>'
//   config: {host, port, version, names: [a, b], episodeType, episode, seed, renderWidth, renderHeight,
//            viewDistance, spawnMin, spawnMax, maxTicks, warmupMs, outDir}
// Writes into outDir, per bot <name>.rgba (T frames of renderHeight x renderWidth x 4, bottom row first,
// as gl.readPixels returns them) and <name>.jsonl (T raw tick rows, see `rawRow`), then episode.json;
// prints one JSON line {"event":"done",...} and exits 0. Any failure exits non-zero with a message.
//
// Tick t of a bot: render the state s_t (pose of bot.entity after physics step t), then take the
// choreography's intent for this tick (controls + look) and apply it; it acts during s_t -> s_{t+1}.
// The raw row holds the pose of s_t and the yaw/pitch after the look, so camera delta = what was applied.
'use strict'
global.THREE = require('three')
global.Worker = require('worker_threads').Worker
const fs = require('fs')
const path = require('path')
const { performance } = require('perf_hooks')
const mineflayer = require('mineflayer')
const { createCanvas } = require('node-canvas-webgl/lib')
const { Viewer, WorldView } = require('prismarine-viewer/viewer')

const cfg = Object.assign({
  host: '127.0.0.1', port: 25565, version: '1.20.1', names: ['Alpha', 'Bravo'], episodeType: 'walkLook',
  episode: 0, seed: 0, renderWidth: 228, renderHeight: 128, viewDistance: 4, spawnMin: 10, spawnMax: 15,
  maxTicks: 3600, warmupMs: 3000, fovDeg: 70, outDir: '.'
}, JSON.parse(process.argv[2] || '{}'))

const TICK_S = 0.05
const EYE = 1.62
const SNEAK_EYE = 1.27
const BURST_DT_MS = 25 // a physicsTick less than this after the previous one is a catch-up tick
const MOVE_KEYS = ['forward', 'back', 'left', 'right']
const REVERSE = { forward: 'back', back: 'forward', left: 'right', right: 'left' }
const CONTROL_KEYS = ['forward', 'back', 'left', 'right', 'jump', 'sprint', 'sneak']
const EVAL_DPS = 171.8873 // 3 rad/s
const CAMERA_DPS = 60
const EPISODE_MIN_TICKS = 300

function log (msg) { process.stderr.write(`[record] ${msg}\n`) }
function fail (msg) { log(`FAILED: ${msg}`); process.exit(1) }
const sleep = (ms) => new Promise(resolve => setTimeout(resolve, ms))

// ---------------------------------------------------------------------------------------------
// Deterministic RNG (mulberry32 over a string hash): the shared draws are identical on both bots.
// ---------------------------------------------------------------------------------------------
function rngFrom (text) {
  let h = 1779033703 ^ text.length
  for (let i = 0; i < text.length; i++) { h = Math.imul(h ^ text.charCodeAt(i), 3432918353); h = (h << 13) | (h >>> 19) }
  let a = h >>> 0
  return () => {
    a = (a + 0x6D2B79F5) | 0
    let t = Math.imul(a ^ (a >>> 15), 1 | a)
    t = (t + Math.imul(t ^ (t >>> 7), 61 | t)) ^ t
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296
  }
}
const xzDist = (a, b) => Math.hypot(a.x - b.x, a.z - b.z)
const uniform = (rng, lo, hi) => lo + (hi - lo) * rng()

// ---------------------------------------------------------------------------------------------
// Choreography primitives: generators yielding one intent per tick ({controls, yaw, pitch} or {barrier})
// ---------------------------------------------------------------------------------------------
function wrapPi (a) { a = (a + Math.PI) % (2 * Math.PI); if (a < 0) a += 2 * Math.PI; return a - Math.PI }
function yawPitchTo (from, to) {
  const dx = to.x - from.x; const dy = to.y - from.y; const dz = to.z - from.z
  return [Math.atan2(-dx, -dz), Math.atan2(dy, Math.hypot(dx, dz))]
}

function * idle (ctx, n, controls = {}) {
  for (let i = 0; i < n; i++) yield { controls }
}
function * look (ctx, yaw, pitch, dps) {
  const step = (dps * Math.PI / 180) * TICK_S
  for (let i = 0; i < 400; i++) {
    const dyaw = wrapPi(yaw - ctx.yaw); const dpitch = pitch - ctx.pitch
    if (Math.abs(dyaw) < 1e-4 && Math.abs(dpitch) < 1e-4) return
    const n = Math.max(Math.abs(dyaw), Math.abs(dpitch)) / step
    const f = n <= 1 ? 1 : 1 / n
    yield { controls: {}, yaw: ctx.yaw + dyaw * f, pitch: ctx.pitch + dpitch * f }
  }
}
function * lookAtOther (ctx, dps) {
  const o = ctx.otherPos()
  if (!o) throw new Error(`${ctx.name} does not see the other player`)
  const [yaw, pitch] = yawPitchTo(ctx.bot.entity.position, o)
  yield * look(ctx, yaw, pitch, dps)
}
function * walk (ctx, key, dist, timeoutTicks = 100) {
  const start = ctx.bot.entity.position.clone()
  for (let i = 0; i < timeoutTicks; i++) {
    if (xzDist(ctx.bot.entity.position, start) >= dist) return
    yield { controls: { [key]: true } }
  }
}
function * walkBack (ctx, key, start, tol = 1.0, timeoutTicks = 100) {
  for (let i = 0; i < timeoutTicks; i++) {
    if (xzDist(ctx.bot.entity.position, start) <= tol) return
    yield { controls: { [key]: true } }
  }
}
function * sneakSignal (ctx) {
  yield * idle(ctx, 5, { sneak: true })
  yield * idle(ctx, 25)
  ctx.startTick = ctx.tick
}
function * padTo (ctx, n) {
  yield * idle(ctx, ctx.startTick + n - ctx.tick)
}
function * barrier (ctx, name) { yield { barrier: name } }

// ---------------------------------------------------------------------------------------------
// Episode types (engine-spec §5.2, §6)
// ---------------------------------------------------------------------------------------------
function * randomWalk (ctx) {
  yield * idle(ctx, Math.round(uniform(ctx.rng, 0.2, 0.5) / TICK_S))
  const key = MOVE_KEYS[Math.floor(ctx.rng() * 4)]
  const start = ctx.bot.entity.position.clone()
  yield * walk(ctx, key, uniform(ctx.rng, 3, 4))
  if (ctx.rng() < 0.25) yield * idle(ctx, Math.round(uniform(ctx.rng, 1, 3) / TICK_S), { jump: true })
  yield * walkBack(ctx, REVERSE[key], start)
  if (ctx.rng() < 0.25) yield * idle(ctx, Math.round(uniform(ctx.rng, 1, 3) / TICK_S), { jump: true })
}

const EPISODES = {
  * walkLook (ctx) {
    for (let it = 0; it < 3; it++) {
      yield * barrier(ctx, `walkLook_${it}`)
      const actionCount = 2 + Math.floor(ctx.shared() * 3)
      const mode = ['both_bots_walk', 'lower_name_walks', 'bigger_name_walks'][Math.floor(ctx.shared() * 3)]
      yield * lookAtOther(ctx, CAMERA_DPS)
      const walks = mode === 'both_bots_walk' || ((mode === 'lower_name_walks') === ctx.isLower)
      if (walks) for (let k = 0; k < actionCount; k++) yield * randomWalk(ctx)
    }
  },
  * rotationEval (ctx) {
    yield * barrier(ctx, 'rotationEval_phase')
    yield * lookAtOther(ctx, EVAL_DPS)
    yield * barrier(ctx, 'rotationEval_signal')
    const kase = cfg.episode % 6
    const rotator = ctx.sortedNames[kase < 3 ? 0 : 1]
    const degrees = [40, -40, 180][kase % 3]
    ctx.evalMetadata = { bots_chosen: [rotator], rotation_degrees: degrees, camera_speed_degrees_per_sec: EVAL_DPS, case_num: kase }
    if (ctx.name !== rotator) return
    yield * sneakSignal(ctx)
    yield * look(ctx, ctx.yaw + degrees * Math.PI / 180, ctx.pitch, EVAL_DPS)
    yield * padTo(ctx, EPISODE_MIN_TICKS)
  },
  // A short smoke type for tests/benchmarks (not a paper type): both bots turn to each other and hold still.
  * lookAtEachOther (ctx) {
    yield * barrier(ctx, 'lookAtEachOther')
    yield * lookAtOther(ctx, EVAL_DPS)
    yield * idle(ctx, Math.max(0, (cfg.smokeTicks || 200) - ctx.tick))
  },
  * oneLooksAwayEval (ctx) { yield * lookAway(ctx, 'oneLooksAwayEval', [ctx.sortedNames[cfg.episode % 2]]) },
  * bothLookAwayEval (ctx) { yield * lookAway(ctx, 'bothLookAwayEval', ctx.sortedNames) }
}
EPISODES.rotationEval.isEval = EPISODES.oneLooksAwayEval.isEval = EPISODES.bothLookAwayEval.isEval = true

function * lookAway (ctx, type, actors) {
  yield * barrier(ctx, `${type}_phase`)
  yield * lookAtOther(ctx, EVAL_DPS)
  yield * barrier(ctx, `${type}_signal`)
  const dir = ctx.shared() < 0.5 ? -1 : 1
  const offset = 90 * dir + ctx.shared() * 45 - 22.5
  ctx.evalMetadata = { bots_chosen: actors, mode: type, camera_speed_degrees_per_sec: EVAL_DPS, look_away_offset_deg: offset, look_away_direction: dir, freeze_ticks: 60 }
  if (!actors.includes(ctx.name)) return
  const yaw0 = ctx.yaw; const pitch0 = ctx.pitch
  yield * sneakSignal(ctx)
  yield * look(ctx, yaw0 + Math.PI + offset * Math.PI / 180, pitch0, EVAL_DPS)
  yield * idle(ctx, 60)
  yield * look(ctx, yaw0, pitch0, EVAL_DPS)
  yield * padTo(ctx, EPISODE_MIN_TICKS)
}

// ---------------------------------------------------------------------------------------------
// Bots, views and the tick loop
// ---------------------------------------------------------------------------------------------
function makeBot (name) {
  const bot = mineflayer.createBot({ host: cfg.host, port: cfg.port, username: name, auth: 'offline', version: cfg.version, viewDistance: 'tiny' })
  bot.on('kicked', (reason) => fail(`${name} kicked: ${JSON.stringify(reason)}`))
  bot.on('error', (err) => fail(`${name} error: ${err && err.stack ? err.stack : err}`))
  return bot
}

function makeView (bot) {
  const w = cfg.renderWidth; const h = cfg.renderHeight
  const canvas = createCanvas(w, h)
  const renderer = new THREE.WebGLRenderer({ canvas })
  const viewer = new Viewer(renderer)
  if (!viewer.setVersion(cfg.version)) throw new Error(`prismarine-viewer does not support ${cfg.version}`)
  viewer.camera.fov = cfg.fovDeg
  viewer.camera.aspect = w / h
  viewer.camera.updateProjectionMatrix()
  const updateEntity = viewer.updateEntity.bind(viewer)
  viewer.updateEntity = (e) => { delete e.username; updateEntity(e) } // name tags render as white boxes
  const worldView = new WorldView(bot.world, cfg.viewDistance, bot.entity.position)
  viewer.listen(worldView)
  worldView.init(bot.entity.position)
  worldView.listenToBot(bot)
  bot.on('move', () => worldView.updatePosition(bot.entity.position))
  const gl = renderer.getContext()
  const pixels = new Uint8Array(w * h * 4)
  return {
    viewer,
    render (pos, yaw, pitch, sneaking) {
      viewer.camera.position.set(pos.x, pos.y + (sneaking ? SNEAK_EYE : EYE), pos.z)
      viewer.camera.rotation.set(pitch, yaw, 0, 'ZYX')
      viewer.update()
      renderer.render(viewer.scene, viewer.camera)
      gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, pixels)
      return pixels
    }
  }
}

async function main () {
  if (!EPISODES[cfg.episodeType]) fail(`unknown episodeType ${cfg.episodeType}; known: ${Object.keys(EPISODES)}`)
  fs.mkdirSync(cfg.outDir, { recursive: true })
  const names = cfg.names
  const sortedNames = [...names].sort()
  // One after the other: a player joining while the other is mid-login is not announced to it.
  const bots = []
  for (const name of names) {
    const bot = makeBot(name)
    await new Promise((resolve) => bot.once('spawn', resolve))
    bots.push(bot)
  }
  log('both bots spawned')
  // Spread the bots U(spawnMin, spawnMax) apart on the flat surface around the origin.
  const place = rngFrom(`place_${cfg.seed}_${cfg.episode}`)
  const d = uniform(place, cfg.spawnMin, cfg.spawnMax); const ang = place() * 2 * Math.PI
  const spots = [[0, 0], [Math.round(d * Math.cos(ang)), Math.round(d * Math.sin(ang))]]
  bots.forEach((b, i) => b.chat(`/tp ${spots[i][0]} 5 ${spots[i][1]}`))
  bots.forEach(b => b.chat('/time set 6000'))
  const deadline = Date.now() + 15000
  while (!bots.every((b, i) => b.players[names[1 - i]] && b.players[names[1 - i]].entity &&
    xzDist(b.entity.position, { x: spots[i][0] + 0.5, z: spots[i][1] + 0.5 }) < 0.1)) {
    if (Date.now() > deadline) fail(`bots did not see each other / reach their spawn spots within 15 s: ${JSON.stringify(bots.map((b, i) => ({ pos: b.entity.position, spot: spots[i], seesOther: !!(b.players[names[1 - i]] && b.players[names[1 - i]].entity) })))}`)
    await sleep(100)
  }
  const views = bots.map(makeView)
  // Face each other before recording (instant, not recorded).
  bots.forEach((b, i) => {
    const [yaw, pitch] = yawPitchTo(b.entity.position, b.players[names[1 - i]].entity.position)
    b.look(yaw, pitch, true)
  })
  await sleep(cfg.warmupMs) // chunk meshing warm-up (~2.5 s before the first good frame)
  await Promise.race([Promise.all(views.map(v => v.viewer.waitForChunksToRender())), sleep(10000)])
  log('views warmed up; recording')

  const episodeType = cfg.episodeType
  const arrived = {} // barrier name -> Set of bot names
  const states = bots.map((bot, i) => {
    const name = names[i]; const other = names[1 - i]
    const ctx = {
      bot, name, sortedNames, isLower: name === sortedNames[0], tick: -1, startTick: null, evalMetadata: {},
      yaw: bot.entity.yaw, pitch: bot.entity.pitch,
      shared: rngFrom(`${cfg.seed + 12345}_${cfg.episode}`),
      rng: rngFrom(`${cfg.seed + 12345}_${cfg.episode}_${name}`),
      otherPos: () => bot.players[other] && bot.players[other].entity ? bot.players[other].entity.position : null
    }
    const script = (function * () { yield * idle(ctx, 20); yield * EPISODES[episodeType](ctx) })()
    return {
      name, ctx, script, waiting: null, finished: false, stopped: false, t: 0, lastMs: null, bursts: 0,
      fd: fs.openSync(path.join(cfg.outDir, `${name}.rgba`), 'w'),
      rows: fs.openSync(path.join(cfg.outDir, `${name}.jsonl`), 'w')
    }
  })
  let stopAt = null
  let resolveDone
  const done = new Promise(resolve => { resolveDone = resolve })

  function onTick (i) {
    const s = states[i]; const bot = bots[i]; const ctx = s.ctx
    if (s.stopped) return
    const now = performance.now()
    const dt = s.lastMs === null ? null : now - s.lastMs
    if (dt !== null && dt < BURST_DT_MS) s.bursts++
    s.lastMs = now
    const pos = bot.entity.position.clone(); const yaw = bot.entity.yaw; const pitch = bot.entity.pitch
    const sneaking = bot.getControlState('sneak')
    fs.writeSync(s.fd, views[i].render(pos, yaw, pitch, sneaking))
    // The choreography's intent for this tick.
    ctx.tick = s.t; ctx.yaw = yaw; ctx.pitch = pitch
    let intent = { controls: {} }
    if (s.waiting && arrived[s.waiting].size === bots.length) s.waiting = null
    if (!s.waiting && !s.finished) {
      const r = s.script.next()
      if (r.done) s.finished = true
      else if (r.value.barrier) {
        s.waiting = r.value.barrier
        if (!arrived[s.waiting]) arrived[s.waiting] = new Set()
        arrived[s.waiting].add(s.name)
      } else intent = r.value
    }
    for (const k of CONTROL_KEYS) bot.setControlState(k, !!intent.controls[k])
    if (intent.yaw !== undefined) bot.look(intent.yaw, intent.pitch, true)
    const row = {
      t: s.t, x: pos.x, y: pos.y, z: pos.z, yaw, pitch, yaw_next: bot.entity.yaw, pitch_next: bot.entity.pitch,
      controls: Object.fromEntries(CONTROL_KEYS.map(k => [k, !!intent.controls[k]])),
      events: { attack: 0, use: 0, place_block: 0, mine: false, hotbar: null },
      quickBarSlot: bot.quickBarSlot, renderTime: Date.now(), physicsTime: now,
      worldAgeTicks: bot.time && bot.time.age !== undefined ? Number(bot.time.age) : null,
      isInWater: !!bot.entity.isInWater, dtMs: dt, waiting: s.waiting
    }
    fs.writeSync(s.rows, JSON.stringify(row) + '\n')
    s.t++
    if (stopAt === null && states.every(x => x.finished)) stopAt = Math.max(...states.map(x => x.t))
    if (stopAt === null && s.t >= cfg.maxTicks) stopAt = s.t
    if (stopAt !== null && s.t >= stopAt) {
      s.stopped = true
      fs.closeSync(s.fd); fs.closeSync(s.rows)
      if (states.every(x => x.stopped)) resolveDone()
    }
  }
  bots.forEach((b, i) => b.on('physicsTick', () => {
    try { onTick(i) } catch (err) { fail(`tick of ${names[i]}: ${err && err.stack ? err.stack : err}`) }
  }))
  await done
  const info = {
    episodeType, episode: cfg.episode, seed: cfg.seed, names, isEval: !!EPISODES[episodeType].isEval,
    renderWidth: cfg.renderWidth, renderHeight: cfg.renderHeight, fovDeg: cfg.fovDeg, eyeHeight: EYE,
    aborted: states.some(s => !s.finished), abortReason: states.some(s => !s.finished) ? `episode exceeded maxTicks=${cfg.maxTicks}` : '',
    bots: Object.fromEntries(states.map(s => [s.name, { frames: s.t, bursts: s.bursts, startTick: s.ctx.startTick, evalMetadata: s.ctx.evalMetadata }]))
  }
  const tmp = path.join(cfg.outDir, `episode.json.tmp-${process.pid}`)
  fs.writeFileSync(tmp, JSON.stringify(info, null, 2))
  fs.renameSync(tmp, path.join(cfg.outDir, 'episode.json'))
  process.stdout.write(JSON.stringify({ event: 'done', frames: states.map(s => s.t), bursts: states.map(s => s.bursts) }) + '\n')
  bots.forEach(b => b.quit())
  setTimeout(() => process.exit(0), 200)
}

process.on('SIGTERM', () => process.exit(143))
process.on('SIGINT', () => process.exit(130))
process.stdin.on('end', () => process.exit(1)) // the supervisor died
process.stdin.resume()
main().catch(err => fail(err && err.stack ? err.stack : String(err)))
