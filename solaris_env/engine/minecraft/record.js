#!/usr/bin/env node
// Records one two-bot episode on a running server (server.js): both first-person views are rendered
// in this process by prismarine-viewer (headless-gl on Xvfb) on every tick of one 20 Hz clock that steps
// both bots' physics, together with that tick's raw action data, so frames and actions align by
// construction and tick t is the same game moment for both bots. The choreographies are episodes.js's.
//
// Usage: node record.js '<json config>'
//   config: {host, port, version, names: [a, b], episodeType, episode, instance, seed, renderWidth, renderHeight,
//            viewDistance, spawnMin, spawnMax, maxTicks, warmupMs, outDir, smokeTicks (lookAtEachOther)}
// Writes into outDir, per bot <name>.rgba (T frames of renderHeight x renderWidth x 4, bottom row first,
// as gl.readPixels returns them) and <name>.jsonl (T raw tick rows, see `rawRow`), then episode.json;
// prints one JSON line {"event":"done",...} and exits 0. Any failure exits non-zero with a message.
//
// Tick t of a bot: render the state s_t (pose of bot.entity after physics step t), then take the
// choreography's intent for this tick (controls + look) and apply it; it acts during s_t -> s_{t+1}.
// The raw row holds the pose of s_t and the yaw/pitch after the look, so camera delta = what was applied.
'use strict'
const fs = require('fs')
const path = require('path')
const { performance } = require('perf_hooks')
const common = require('./common') // bots, views, RNG and angle helpers shared with env_bridge.js
const { EYE, BURST_DT_MS, CONTROL_KEYS, rngFrom, xzDist } = common

const cfg = Object.assign({
  host: '127.0.0.1', port: 25565, version: '1.20.1', names: ['Alpha', 'Bravo'], episodeType: 'walkLook',
  episode: 0, instance: 0, seed: 0, renderWidth: 228, renderHeight: 128, viewDistance: 4, spawnMin: 10, spawnMax: 15,
  maxTicks: 3600, warmupMs: 3000, fovDeg: 70, outDir: '.'
}, JSON.parse(process.argv[2] || '{}'))

const PRE_ROLL_TICKS = 20 // the reference sleeps 1 s after recording starts
const SURFACE_Y = 5 // feet height on server.js's superflat world

function log (msg) { process.stderr.write(`[record] ${msg}\n`) }
function fail (msg) { log(`FAILED: ${msg}`); process.exit(1) }
const sleep = (ms) => new Promise(resolve => setTimeout(resolve, ms))

// The episode choreographies (docs/engine.md §5-§6) and the spawn/item plan live in episodes.js.
const { EPISODES, EVAL_TYPES, planEpisode, yawTo, pitchTo } = require('./episodes')

// ---------------------------------------------------------------------------------------------
// Bots, views and the tick loop
// ---------------------------------------------------------------------------------------------
// common.makeBot also fixes up flying-squid's knockback packets (entity_velocity)
const makeBot = (name) => common.makeBot(cfg, name, fail)
const makeView = (bot) => common.makeView(cfg, bot)

// Apply one choreography intent (see episodes.js) to a bot on its physics tick. Once-events land in
// `pending` (read and reset by the tick's row): hotbar on the key press, attack on the swing,
// place_block when the server confirms the block (as the reference's recorder does); `dig` hooks
// count digs in progress (mine is sustained while one runs).
function applyIntent (bot, name, intent, pending, dig) {
  if (intent.hotbar !== undefined) {
    if (!(intent.hotbar >= 1 && intent.hotbar <= 9)) throw new Error(`${name}: intent.hotbar must be 1..9, got ${intent.hotbar}`)
    bot.setQuickBarSlot(intent.hotbar - 1)
    pending.hotbar = intent.hotbar
  }
  for (const k of CONTROL_KEYS) bot.setControlState(k, !!intent.controls[k])
  if (intent.yaw !== undefined) bot.look(intent.yaw, intent.pitch, true)
  if (intent.attack) {
    bot.attack(intent.attack)
    pending.attack = 1
    pending.hits.push(intent.attack.username || null)
  }
  if (intent.place) {
    const ref = bot.blockAt(intent.place.ref)
    const dest = intent.place.ref.plus(intent.place.face)
    pending.clicks++
    if (ref && bot.heldItem) {
      // One watcher per cell: a click the server ignored must not count a later block there twice.
      const key = `blockUpdate:${dest}`
      if (pending.watchers.has(key)) bot.removeListener(key, pending.watchers.get(key))
      const watch = (oldB, newB) => {
        if (!newB || newB.name === 'air') return
        bot.removeListener(key, watch); pending.watchers.delete(key)
        pending.place_block = 1; pending.placed.push([dest.x, dest.y, dest.z, newB.name])
      }
      pending.watchers.set(key, watch)
      bot.on(key, watch)
      bot._genericPlace(ref, intent.place.face, { forceLook: 'ignore', swingArm: 'right' })
        .catch(err => log(`${name}: place at ${dest} failed: ${err.message}`))
    }
  }
  if (intent.dig) {
    const block = bot.blockAt(intent.dig.pos)
    if (block && block.name !== 'air') {
      const { x, y, z } = intent.dig.pos; const was = block.name
      dig.start()
      bot.dig(block, 'ignore', intent.dig.face)
        .then(() => { const b = bot.blockAt(intent.dig.pos); if (!b || b.name === 'air') pending.mined.push([x, y, z, was]) })
        .catch(err => log(`${name}: dig at ${intent.dig.pos} failed: ${err.message}`))
        .finally(dig.end)
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
  // The episode's plan (spawn spots around the origin, items, shared layout). Far teleports strand a bot
  // in unloaded chunks, so every episode plays near the origin on a fresh server (collect.py restarts it).
  const place = rngFrom(`place_${cfg.seed}_${cfg.instance}_${cfg.episode}`)
  const plan = planEpisode(cfg.episodeType, cfg, place)
  const spots = plan.spots
  if (plan.layout.centre) plan.layout.centre = [plan.layout.centre[0], SURFACE_Y, plan.layout.centre[2]]
  bots.forEach((b, i) => b.chat(`/tp ${spots[i][0]} ${SURFACE_Y} ${spots[i][1]}`))
  bots.forEach(b => b.chat('/time set 6000'))
  bots.forEach((b, i) => { for (const [item, count] of plan.items[names[i]]) b.chat(`/give ${names[i]} ${item} ${count}`) })
  const hasItems = (b, i) => plan.items[names[i]].every(([item]) => b.inventory.items().some(it => it.name === item))
  const deadline = Date.now() + 15000
  const atSpot = (b, i) => xzDist(b.entity.position, { x: spots[i][0] + 0.5, z: spots[i][1] + 0.5 }) < 0.1
  let retp = Date.now() + 2000 // flying-squid's delayed login position can undo a /tp sent right after spawn
  while (!bots.every((b, i) => b.players[names[1 - i]] && b.players[names[1 - i]].entity && hasItems(b, i) && atSpot(b, i))) {
    if (Date.now() > retp) {
      bots.forEach((b, i) => { if (!atSpot(b, i)) { log(`${names[i]} is not at its spot yet: /tp again`); b.chat(`/tp ${spots[i][0]} ${SURFACE_Y} ${spots[i][1]}`) } })
      retp = Date.now() + 2000
    }
    if (Date.now() > deadline) fail(`bots did not see each other / reach their spawn spots / get their items within 15 s: ${JSON.stringify(bots.map((b, i) => ({ pos: b.entity.position, spot: spots[i], seesOther: !!(b.players[names[1 - i]] && b.players[names[1 - i]].entity), items: b.inventory.items().map(it => it.name) })))}`)
    await sleep(100)
  }
  // Empty hand: select the first empty hotbar slot (not recorded).
  bots.forEach(b => { const s = [...Array(9).keys()].find(k => !b.inventory.slots[36 + k]); if (s !== undefined) b.setQuickBarSlot(s) })
  const views = bots.map(makeView)
  // Face each other before recording (instant, not recorded).
  bots.forEach((b, i) => {
    const o = b.players[names[1 - i]].entity.position
    b.look(yawTo(b.entity.position, o), pitchTo(b.entity.position, o), true)
  })
  await sleep(cfg.warmupMs) // chunk meshing warm-up (~2.5 s before the first good frame)
  await Promise.race([Promise.all(views.map(v => v.viewer.waitForChunksToRender())), sleep(10000)])
  log('views warmed up; recording')

  const episodeType = cfg.episodeType
  const arrived = {} // barrier name -> Set of bot names
  const board = {} // barrier payloads and posts, shared by both choreographies
  const states = bots.map((bot, i) => {
    const name = names[i]; const other = names[1 - i]
    const pending = { attack: 0, place_block: 0, hotbar: null, placed: [], mined: [], hits: [], clicks: 0, watchers: new Map() } // events since the previous row
    let digs = 0 // digs in progress (mine is sustained while > 0)
    const ctx = {
      bot, name, other, sortedNames, isLower: name === sortedNames[0], episode: cfg.episode, tick: -1,
      startTick: null, evalMetadata: {}, summary: {}, board, layout: plan.layout, smokeTicks: cfg.smokeTicks,
      // the reference's seedrandom("<12345 + instance>_<N>"), as the voxel engine's runner
      shared: rngFrom(`${cfg.seed + 12345 + cfg.instance}_${cfg.episode}`),
      rng: rngFrom(`${cfg.seed + 12345 + cfg.instance}_${cfg.episode}_${name}`),
      digging: () => digs > 0
    }
    const apply = (intent) => applyIntent(bot, name, intent, pending, { start: () => digs++, end: () => digs-- })
    const script = (function * () { for (let k = 0; k < PRE_ROLL_TICKS; k++) yield { controls: {} }; yield * EPISODES[episodeType](ctx) })()
    return {
      name, ctx, script, pending, apply, waiting: null, finished: false, stopped: false, t: 0, lastMs: null, bursts: 0, look: null, lookResets: 0,
      fd: fs.openSync(path.join(cfg.outDir, `${name}.rgba`), 'w'),
      rows: fs.openSync(path.join(cfg.outDir, `${name}.jsonl`), 'w')
    }
  })
  bots.forEach((b, i) => b._client.on('position', (p) => {
    log(`${names[i]}: position packet from the server at tick ${states[i].t} (yaw ${p.yaw}, pitch ${p.pitch}, flags ${JSON.stringify(p.flags)})`)
  }))
  let abortReason = ''
  let resolveDone
  const done = new Promise(resolve => { resolveDone = resolve })

  // The choreography's intent for bot i on its tick s.t (the state s_t is what it reads), before rendering:
  // a tick on which every choreography has ended (or one gave up) is not recorded at all.
  function decide (i) {
    const s = states[i]; const bot = bots[i]; const ctx = s.ctx
    // flying-squid answers some moves with a position packet whose yaw/pitch are its byte-encoded angles
    // read as degrees (a jump of up to ~20 deg that the player never made): keep the commanded camera, so
    // the recorded camera deltas sum to the view's rotation.
    if (s.look && (bot.entity.yaw !== s.look.yaw || bot.entity.pitch !== s.look.pitch)) {
      s.lookResets++
      log(`${s.name} tick ${s.t}: the server turned the camera (${(bot.entity.yaw - s.look.yaw).toFixed(4)}, ${(bot.entity.pitch - s.look.pitch).toFixed(4)} rad); restored`)
      bot.entity.yaw = s.look.yaw; bot.entity.pitch = s.look.pitch
    }
    ctx.tick = s.t
    // A barrier releases every bot on the tick after the last one reached it (the same tick for all).
    if (s.waiting && arrived[s.waiting].completeTick !== undefined && arrived[s.waiting].completeTick < s.t) s.waiting = null
    if (s.waiting || s.finished) return { controls: {} }
    let r
    try { r = s.script.next() } catch (err) { // the choreography gave up: the episode aborts for both bots
      log(`${s.name} aborts the episode: ${err && err.stack ? err.stack : err}`)
      abortReason = abortReason || `${s.name}: ${err && err.message ? err.message : err}`
      r = { done: true }
    }
    if (r.done) { s.finished = true; return { controls: {} } }
    if (r.value.barrier) {
      s.waiting = r.value.barrier
      if (!arrived[s.waiting]) arrived[s.waiting] = new Set()
      arrived[s.waiting].add(s.name)
      if (arrived[s.waiting].size === bots.length) arrived[s.waiting].completeTick = s.t
      return { controls: {} }
    }
    return r.value
  }

  // Tick s.t of bot i: render the state s_t, apply the intent, write the raw row.
  function record (i, intent, now) {
    const s = states[i]; const bot = bots[i]; const ctx = s.ctx
    const dt = s.lastMs === null ? null : now - s.lastMs
    if (dt !== null && dt < BURST_DT_MS) s.bursts++
    s.lastMs = now
    const pos = bot.entity.position.clone(); const yaw = bot.entity.yaw; const pitch = bot.entity.pitch
    const sneaking = bot.getControlState('sneak')
    fs.writeSync(s.fd, views[i].render(pos, yaw, pitch, sneaking))
    s.apply(intent)
    s.look = { yaw: bot.entity.yaw, pitch: bot.entity.pitch }
    const row = {
      t: s.t, x: pos.x, y: pos.y, z: pos.z, yaw, pitch, yaw_next: bot.entity.yaw, pitch_next: bot.entity.pitch,
      controls: Object.fromEntries(CONTROL_KEYS.map(k => [k, !!intent.controls[k]])),
      events: { attack: s.pending.attack, use: 0, place_block: s.pending.place_block, mine: ctx.digging(), hotbar: s.pending.hotbar,
        placed: s.pending.placed, mined: s.pending.mined, hits: s.pending.hits },
      quickBarSlot: bot.quickBarSlot, renderTime: Date.now(), physicsTime: now,
      worldAgeTicks: bot.time && bot.time.age !== undefined ? Number(bot.time.age) : null,
      isInWater: !!bot.entity.isInWater, dtMs: dt, waiting: s.waiting
    }
    Object.assign(s.pending, { attack: 0, place_block: 0, hotbar: null, placed: [], mined: [], hits: [] })
    fs.writeSync(s.rows, JSON.stringify(row) + '\n')
    s.t++
  }

  function stopAll () {
    for (const s of states) { s.stopped = true; fs.closeSync(s.fd); fs.closeSync(s.rows) }
    resolveDone()
  }

  // One tick of the episode for both bots (after the physics step).
  function onTick () {
    if (states[0].stopped) return
    const intents = states.map((s, i) => decide(i))
    if (abortReason || states.every(s => s.finished)) { stopAll(); return }
    const now = performance.now()
    states.forEach((s, i) => record(i, intents[i], now))
    if (states[0].t >= cfg.maxTicks) stopAll()
  }
  // One 20 Hz clock drives both bots in lockstep (mineflayer's per-bot physics timers drift apart under
  // load): each tick steps Mineflayer's physics for every bot, then renders and acts for every bot, so
  // tick t of Alpha and tick t of Bravo are the same game moment. A late timer runs up to
  // common.MAX_CATCHUP_TICKS ticks back to back (catch-up ticks, counted from dtMs); beyond that the clock
  // skips ahead (the game ran slower than real time for a moment).
  const physics = bots.map((b, i) => common.makePhysicsStep(b, names[i]))
  bots.forEach(b => { b.physicsEnabled = false }) // mineflayer keeps sending positions; we simulate
  function gameTick () {
    physics.forEach(stepPhysics => stepPhysics())
    onTick()
  }
  let skippedTicks = 0 // ticks of wall time never played
  const clock = common.startLockstepClock({
    maxCatchup: common.MAX_CATCHUP_TICKS,
    tick: () => { try { gameTick() } catch (err) { fail(`tick ${clock.n}: ${err && err.stack ? err.stack : err}`) } },
    onSkip: (n) => { if (!states[0].stopped) skippedTicks += n },
    running: () => !states.every(x => x.stopped)
  })
  await done
  const info = {
    episodeType, episode: cfg.episode, seed: cfg.seed, names, isEval: EVAL_TYPES.has(episodeType), summary: Object.fromEntries(states.map(s => [s.name, { ...s.ctx.summary, placeClicks: s.pending.clicks }])),
    renderWidth: cfg.renderWidth, renderHeight: cfg.renderHeight, fovDeg: cfg.fovDeg, eyeHeight: EYE, skippedTicks,
    aborted: !!abortReason || states.some(s => !s.finished), abortReason: abortReason || (states.some(s => !s.finished) ? `episode exceeded maxTicks=${cfg.maxTicks}` : ''),
    bots: Object.fromEntries(states.map(s => [s.name, { frames: s.t, bursts: s.bursts, lookResets: s.lookResets, startTick: s.ctx.startTick, evalMetadata: s.ctx.evalMetadata }]))
  }
  const tmp = path.join(cfg.outDir, `episode.json.tmp-${process.pid}`)
  fs.writeFileSync(tmp, JSON.stringify(info, null, 2))
  fs.renameSync(tmp, path.join(cfg.outDir, 'episode.json'))
  process.stdout.write(JSON.stringify({ event: 'done', frames: states.map(s => s.t), bursts: states.map(s => s.bursts) }) + '\n')
  bots.forEach(b => b.quit())
  setTimeout(() => process.exit(0), 200)
}

if (require.main === module) {
  process.on('SIGTERM', () => process.exit(143))
  process.on('SIGINT', () => process.exit(130))
  process.stdin.on('end', () => process.exit(1)) // the supervisor died
  process.stdin.resume()
  main().catch(err => fail(err && err.stack ? err.stack : String(err)))
}
