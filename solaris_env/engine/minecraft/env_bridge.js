#!/usr/bin/env node
// The env bridge: the players of RealParallelEnv(backend="minecraft") as mineflayer bots on a running
// server (server.js), each with its first-person view rendered in this process by prismarine-viewer, stepped
// in real time (20 Hz) on behalf of a Python client over one TCP connection on 127.0.0.1.
//
// Usage: node env_bridge.js '<json config>'
//   config: {host, port, version, names, renderWidth, renderHeight, viewDistance, fovDeg, warmupMs}
// Logs the bots in (one after the other), then listens on 127.0.0.1 (any free port) and prints one line
// {"event":"ready","port":N} on stdout. Exits when the client sends close, when stdin closes (the supervisor
// died) or on SIGTERM.
//
// Protocol: the client sends one JSON object per line; every request gets one JSON header line, followed
// by `frameBytes` raw bytes when the header has them (the frames: bot by bot, frame by frame, RGBA
// renderHeight x renderWidth x 4, bottom row first as gl.readPixels returns them).
//   {"op":"reset","spots":[{x,y,z,yaw,pitch} per bot]}  -> teleport every bot to its block (x, y, z),
//       face (yaw, pitch), release all keys, restore the cells dug or placed since the last reset, refill the
//       start kit (episodes.js COMMON_ITEMS, as the recorder), select the empty hotbar slot 5; reply
//       {op,tick,bots:[{poses:[pose]}],frameBytes} (one frame).
//   {"op":"step","ticks":[[action per bot] per tick]}   -> play k = len(ticks) ticks; reply {op,k,tick,
//       idleTicks,idleCatchup,catchup,dropped,lateMs,bots:[{poses:[pose per tick]}],frameBytes} (k frames/bot).
//       action: {controls:{forward,back,left,right,jump,sprint,sneak}, dyaw, dpitch (radians, Mineflayer
//       sign), attack (0/1), use (0/1), hotbar (null or 1..9)}.
//   {"op":"close"}                                        -> reply {op:"closed"} and exit.
//   Errors reply {op:"error",message}.
// pose: {x,y,z,yaw,pitch,sneak,onGround,camera:[dyaw,dpitch] applied before this tick (actual, after
//   Mineflayer's mouse quantisation),hit (a player was attacked),others:{name:[x,y,z] as this bot knows it},
//   mine (a dig is in progress), placed/mined: [[x,y,z,block name]] confirmed since the previous frame}.
//   placed: the server's block update for a cell this bot clicked; mined: this bot's dig finished and the
//   cell is air (flying-squid accepts every finished dig and sends the digger no confirmation).
//
// Ticks. One clock drives every bot: on each 20 Hz tick all bots run one step of Mineflayer's own
// physics (prismarine-physics, the same call as mineflayer's physics plugin, whose loop is switched off
// with physicsEnabled: false so that both bots tick together), then each bot's view is rendered: a frame is
// always the state right after its tick's physics. A step's first action is applied as soon as the request
// arrives (before the next tick's physics), action j+1 right after frame j is rendered. Between steps the
// bots keep ticking in real time holding the last step's movement keys (no camera, no once-keys): those
// are reported as idleTicks. A tick that runs more than BURST_DT_MS after its due time (the event loop was
// busy) is a catch-up tick (counted in catchup / idleCatchup); after common.MAX_CATCHUP_TICKS due ticks in one go the
// clock skips ahead and the skipped ticks are reported as dropped (the game ran slower than real time).
'use strict'
const net = require('net')
const common = require('./common')
const { BURST_DT_MS, CONTROL_KEYS, xzDist } = common
const { Vec3 } = require('vec3')
const { COMMON_ITEMS } = require('./episodes') // the recorder's start kit, in hotbar order

const cfg = Object.assign({
  host: '127.0.0.1', port: 25565, version: '1.20.1', names: ['Alpha', 'Bravo'], renderWidth: 114,
  renderHeight: 64, viewDistance: 4, fovDeg: 70, warmupMs: 3000
}, JSON.parse(process.argv[2] || '{}'))

const REACH = 3.0 // survival attack reach
const BLOCK_REACH = 4.5 // survival block reach from the eye (the voxel engine's REACH)
const BREAK_DELAY_TICKS = 5 // vanilla pause between two broken blocks while attack is held (as the voxel engine)
const USE_REPEAT_TICKS = 4 // vanilla repeats a held right click every 4 ticks (as the voxel engine)
const EMPTY_HAND_SLOT = 4 // the start kit fills slots 0-3; the player starts with an empty hand (hotbar.5)
const KIT_TIMEOUT_MS = 10000
// prismarine-world's BlockFace numbering (the raycast's face, the protocol's direction) -> normal
const FACE_NORMALS = [new Vec3(0, -1, 0), new Vec3(0, 1, 0), new Vec3(0, 0, -1), new Vec3(0, 0, 1), new Vec3(-1, 0, 0), new Vec3(1, 0, 0)]
const REPLACEABLE = new Set(['air', 'cave_air', 'void_air', 'water']) // a block may be placed into these cells
const PITCH_LIMIT = Math.PI / 2
const TELEPORT_TIMEOUT_MS = 20000
const FAR_TELEPORT_BLOCKS = 24 // a teleport farther than this waits for the viewers to mesh the new chunks

function log (msg) { process.stderr.write(`[env_bridge] ${msg}\n`) }
function fail (msg) { log(`FAILED: ${msg}`); process.exit(1) }
const sleep = (ms) => new Promise(resolve => setTimeout(resolve, ms))

const bots = []
const views = []
const physics = []
// Per bot: the dig in progress {pos, name, stateId}, cooldowns (ticks), block events not yet reported
// (placed/mined: [x, y, z, name] as the server confirmed them), one placement watcher per cell.
const acts = []
const edits = new Map() // "x,y,z" -> {pos, stateId}: the cell's block before the first dig/place (reset restores it)
let warmedUp = false
let client = null

// ---------------------------------------------------------------------------------------------
// The game clock
// ---------------------------------------------------------------------------------------------
const clock = { tick: 0 } // ticks played since start
let step = null // the step being played: {ticks, k, frames: [[Buffer]], poses: [[pose]], lateMs, catchup, ...}
let pendingReset = null // resolve(frames, poses) at the next tick
const idle = { ticks: 0, catchup: 0, dropped: 0 }

function startClock () {
  common.startLockstepClock({
    maxCatchup: common.MAX_CATCHUP_TICKS,
    tick: (lateMs) => { try { gameTick(lateMs) } catch (err) { fail(`tick ${clock.tick}: ${err && err.stack ? err.stack : err}`) } },
    onSkip: (n) => { if (step) step.dropped += n; else idle.dropped += n } // the game slows down: reported
  })
}

function gameTick (lateMs) {
  clock.tick++
  for (const s of acts) { // cooldowns run on every tick, played or idle (the voxel engine's per-tick countdown)
    s.digCooldown = Math.max(0, s.digCooldown - 1)
    s.useCooldown = Math.max(0, s.useCooldown - 1)
  }
  physics.forEach(stepPhysics => stepPhysics())
  bots.forEach(b => b.emit('physicsTick'))
  const catchup = lateMs > BURST_DT_MS
  if (pendingReset) {
    const done = pendingReset
    pendingReset = null
    idle.ticks = idle.catchup = idle.dropped = 0
    done(bots.map((b, i) => [renderFrame(i)]), bots.map((b, i) => [pose(i, [0, 0], false)]))
  } else if (step) {
    const f = step.frames[0].length // this tick's frame index
    step.lateMs.push(Math.round(lateMs * 10) / 10)
    if (catchup) step.catchup++
    bots.forEach((b, i) => {
      step.frames[i].push(renderFrame(i))
      step.poses[i].push(pose(i, step.applied[i].camera, step.applied[i].hit, true))
    })
    if (f + 1 < step.k) applyTick(f + 1)
    else finishStep()
  } else {
    idle.ticks++
    if (catchup) idle.catchup++
  }
}

function renderFrame (i) {
  const bot = bots[i]
  return Buffer.from(views[i].render(bot.entity.position, bot.entity.yaw, bot.entity.pitch, bot.getControlState('sneak')))
}

// events: take the block events confirmed since the previous frame (a step's frames; events of idle ticks
// go to the next step's first frame).
function pose (i, camera, hit, events = false) {
  const bot = bots[i]; const p = bot.entity.position; const s = acts[i]
  const others = {}
  for (const name of cfg.names) {
    if (name === cfg.names[i]) continue
    const e = bot.players[name] && bot.players[name].entity
    others[name] = e ? [e.position.x, e.position.y, e.position.z] : null
  }
  return {
    x: p.x, y: p.y, z: p.z, yaw: bot.entity.yaw, pitch: bot.entity.pitch, sneak: bot.getControlState('sneak'),
    onGround: !!bot.entity.onGround, camera, hit, others, mine: !!s.dig,
    placed: events ? s.placed.splice(0) : [], mined: events ? s.mined.splice(0) : []
  }
}

// ---------------------------------------------------------------------------------------------
// Actions
// ---------------------------------------------------------------------------------------------
// One tick's action, in the voxel engine's order: hotbar, camera, attack/dig, use/place (movement keys
// are held for the tick's physics).
function applyAction (i, act) {
  const bot = bots[i]
  for (const k of CONTROL_KEYS) bot.setControlState(k, !!(act.controls && act.controls[k]))
  if (act.hotbar && act.hotbar - 1 !== bot.quickBarSlot) {
    stopDig(i) // another tool: the dig starts over (as the voxel engine)
    bot.setQuickBarSlot(act.hotbar - 1)
  }
  const yaw0 = bot.entity.yaw; const pitch0 = bot.entity.pitch
  if (act.dyaw || act.dpitch) {
    const pitch = Math.max(-PITCH_LIMIT, Math.min(PITCH_LIMIT, pitch0 + (act.dpitch || 0)))
    bot.look(yaw0 + (act.dyaw || 0), pitch, true)
  }
  const hit = attackOrDig(i, !!act.attack)
  if (act.use) use(i)
  return { camera: [bot.entity.yaw - yaw0, bot.entity.pitch - pitch0], hit }
}

// attack: hit the player under the crosshair within REACH, else dig the block under the crosshair within
// BLOCK_REACH (mineflayer's bot.dig, as the recorder: the dig time follows the block's hardness and the held
// tool; it runs on mineflayer's timer, so the clock never waits for it). The dig goes on while attack stays
// pressed on the same block and stops on a tick without attack, on another target or on a hotbar change;
// idle ticks between steps keep it going (the button stays held, as the movement keys). Returns whether a
// player was hit.
function attackOrDig (i, attack) {
  const bot = bots[i]; const s = acts[i]
  if (!attack) { stopDig(i); return false }
  const target = bot.entityAtCursor(REACH) // nearer than the block under the crosshair, if any
  if (target && target.type === 'player') { stopDig(i); bot.attack(target); return true }
  const block = bot.blockAtCursor(BLOCK_REACH)
  if (!block || block.type === 0) { stopDig(i); bot.swingArm(); return false }
  if (s.dig && s.dig.pos.equals(block.position)) return false // still digging it
  stopDig(i)
  if (s.digCooldown > 0) return false
  if (!block.diggable || !Number.isFinite(bot.digTime(block))) { bot.swingArm(); return false } // bedrock
  const d = { pos: block.position.clone(), name: block.name, stateId: block.stateId }
  s.dig = d
  if (process.env.SOLARIS_BRIDGE_DEBUG) log(`${cfg.names[i]} tick ${clock.tick}: dig ${d.name} at ${d.pos} holding ${bot.heldItem ? bot.heldItem.name : 'nothing'} (${bot.digTime(block)} ms)`)
  bot.dig(block, 'ignore')
    .then(() => {
      if (s.dig === d) s.dig = null
      const now = bot.blockAt(d.pos)
      if (now && now.type === 0) {
        noteEdit(d.pos, d.stateId)
        s.mined.push([d.pos.x, d.pos.y, d.pos.z, d.name])
        s.digCooldown = BREAK_DELAY_TICKS
      }
    })
    .catch(() => { if (s.dig === d) s.dig = null }) // aborted (stopDig)
  return false
}

function stopDig (i) {
  const s = acts[i]
  if (!s.dig) return
  s.dig = null
  bots[i].stopDigging() // rejects the dig's promise
}

// use: place the held block against the face under the crosshair within BLOCK_REACH (mineflayer's
// _genericPlace, as the recorder), at most every USE_REPEAT_TICKS ticks; never into a player's box. The
// block counts as placed when the server's block update for the cell arrives.
function use (i) {
  const bot = bots[i]; const s = acts[i]
  if (s.useCooldown > 0) return
  s.useCooldown = USE_REPEAT_TICKS
  const item = bot.heldItem
  if (!item || !bot.registry.blocksByName[item.name]) return
  const ref = bot.blockAtCursor(BLOCK_REACH)
  if (!ref || ref.type === 0 || !FACE_NORMALS[ref.face]) return
  const other = bot.entityAtCursor(BLOCK_REACH) // a player in front of the block takes the click
  if (other && other.type === 'player') return
  const normal = FACE_NORMALS[ref.face]
  const dest = ref.position.plus(normal)
  const there = bot.blockAt(dest)
  if (!there || !REPLACEABLE.has(there.name)) return
  if (bots.some(b => overlapsCell(b.entity.position, dest))) return
  const key = `blockUpdate:${dest}`
  if (s.watchers.has(key)) bot.removeListener(key, s.watchers.get(key)) // one watcher per cell
  const was = there.stateId
  const watch = (oldB, newB) => {
    if (!newB || REPLACEABLE.has(newB.name)) return
    bot.removeListener(key, watch); s.watchers.delete(key)
    noteEdit(dest, was)
    s.placed.push([dest.x, dest.y, dest.z, newB.name])
  }
  s.watchers.set(key, watch)
  bot.on(key, watch)
  bot._genericPlace(ref, normal, { forceLook: 'ignore', swingArm: 'right' })
    .catch(err => log(`${cfg.names[i]}: place at ${dest} failed: ${err.message}`))
}

function overlapsCell (p, c) { // a player's 0.6 x 1.8 box at feet p and the block cell c
  return p.x + 0.3 > c.x && p.x - 0.3 < c.x + 1 && p.z + 0.3 > c.z && p.z - 0.3 < c.z + 1 && p.y < c.y + 1 && p.y + 1.8 > c.y
}

function noteEdit (pos, stateId) {
  const key = `${pos.x},${pos.y},${pos.z}`
  if (!edits.has(key)) edits.set(key, { pos: pos.clone(), stateId })
}

function applyTick (j) {
  step.applied = bots.map((b, i) => applyAction(i, step.ticks[j][i]))
}

function finishStep () {
  const s = step
  step = null
  const frames = s.frames.flat()
  const header = {
    op: 'step', k: s.k, tick: clock.tick, idleTicks: s.idleTicks, idleCatchup: s.idleCatchup,
    idleDropped: s.idleDropped, catchup: s.catchup, dropped: s.dropped, lateMs: s.lateMs,
    bots: s.poses.map(poses => ({ poses })), frameBytes: frames.reduce((n, f) => n + f.length, 0)
  }
  reply(header, frames)
}

// ---------------------------------------------------------------------------------------------
// Requests
// ---------------------------------------------------------------------------------------------
function reply (header, frames = []) {
  if (!client) return
  client.write(JSON.stringify(header) + '\n')
  for (const f of frames) client.write(f)
}

function startStep (req) {
  if (step || pendingReset) throw new Error('step requested while another request is in flight')
  if (!Array.isArray(req.ticks) || req.ticks.length < 1) throw new Error('step needs ticks: a non-empty list')
  for (const t of req.ticks) {
    if (!Array.isArray(t) || t.length !== bots.length) throw new Error(`every tick needs one action per bot (${bots.length})`)
    for (const act of t) {
      if (act.hotbar != null && !(Number.isInteger(act.hotbar) && act.hotbar >= 1 && act.hotbar <= 9)) {
        throw new Error(`action.hotbar must be null or an integer 1..9, got ${JSON.stringify(act.hotbar)}`)
      }
      for (const k of ['attack', 'use']) {
        if (act[k] !== undefined && act[k] !== 0 && act[k] !== 1) throw new Error(`action.${k} must be 0 or 1, got ${JSON.stringify(act[k])}`)
      }
    }
  }
  step = {
    ticks: req.ticks, k: req.ticks.length, frames: bots.map(() => []), poses: bots.map(() => []), lateMs: [],
    catchup: 0, dropped: 0, idleTicks: idle.ticks, idleCatchup: idle.catchup, idleDropped: idle.dropped
  }
  idle.ticks = idle.catchup = idle.dropped = 0
  applyTick(0) // before the next tick's physics
}

async function reset (req) {
  if (step || pendingReset) throw new Error('reset requested while another request is in flight')
  const spots = req.spots
  if (!Array.isArray(spots) || spots.length !== bots.length) throw new Error(`reset needs one spot per bot (${bots.length})`)
  bots.forEach(b => { for (const k of CONTROL_KEYS) b.setControlState(k, false) })
  // a new episode: no dig or placement carries over, the world's dug/placed cells are restored (the same
  // superflat world at every reset) and every bot gets its start kit back, empty hand selected
  acts.forEach((s, i) => {
    stopDig(i)
    for (const [key, watch] of s.watchers) bots[i].removeListener(key, watch)
    s.watchers.clear()
  })
  await restoreEdits()
  await giveKits()
  bots.forEach(b => b.setQuickBarSlot(EMPTY_HAND_SLOT))
  // a bot that wandered off (held keys between steps) comes back to chunks its viewer must mesh again
  const far = bots.some((b, i) => xzDist(b.entity.position, spots[i]) > FAR_TELEPORT_BLOCKS)
  // the server's teleport (its position packet: mineflayer's forcedMove) must have arrived: a bot sent to the
  // spot it stands on looks settled before it, then the late packet lifts it by 0.5 and resets its camera
  const moved = bots.map(() => false)
  const onMoved = bots.map((b, i) => () => { moved[i] = true })
  bots.forEach((b, i) => b.once('forcedMove', onMoved[i]))
  bots.forEach((b, i) => b.chat(`/tp ${spots[i].x} ${spots[i].y} ${spots[i].z}`))
  bots[0].chat('/time set 6000')
  const at = (p, s) => xzDist(p, { x: s.x + 0.5, z: s.z + 0.5 }) < 0.1
  const deadline = Date.now() + TELEPORT_TIMEOUT_MS
  const settled = () => bots.every((b, i) => moved[i] && at(b.entity.position, spots[i]) && b.entity.onGround &&
    cfg.names.every((name, j) => j === i || (b.players[name] && b.players[name].entity && at(b.players[name].entity.position, spots[j]))))
  while (!settled()) {
    if (Date.now() > deadline) {
      bots.forEach((b, i) => b.removeListener('forcedMove', onMoved[i]))
      throw new Error(`bots did not reach their spots / see each other within ${TELEPORT_TIMEOUT_MS} ms: ` +
        JSON.stringify(bots.map((b, i) => ({ pos: b.entity.position, spot: spots[i], onGround: b.entity.onGround }))))
    }
    await sleep(50)
  }
  bots.forEach((b, i) => b.look(spots[i].yaw, spots[i].pitch, true))
  if (!warmedUp || far) { // chunk meshing warm-up (~2.5 s before the first good frame)
    await sleep(cfg.warmupMs)
    await Promise.race([Promise.all(views.map(v => v.viewer.waitForChunksToRender())), sleep(10000)])
    warmedUp = true
  }
  acts.forEach(s => { s.placed.length = 0; s.mined.length = 0; s.digCooldown = 0; s.useCooldown = 0 })
  const [frames, poses] = await new Promise(resolve => { pendingReset = (f, p) => resolve([f, p]) })
  const flat = frames.flat()
  reply({ op: 'reset', tick: clock.tick, bots: poses.map(p => ({ poses: p })), frameBytes: flat.reduce((n, f) => n + f.length, 0) }, flat)
}

// /setblock every edited cell back to its block; waits until every bot's world shows it.
async function restoreEdits () {
  if (edits.size === 0) return
  const reg = bots[0].registry
  const cells = [...edits.values()]
  edits.clear()
  for (const { pos, stateId } of cells) {
    const b = reg.blocksByStateId[stateId]
    bots[0].chat(`/setblock ${pos.x} ${pos.y} ${pos.z} ${b.id} ${stateId - b.minStateId}`)
  }
  await waitFor(() => cells.every(c => bots.every(b => { const now = b.blockAt(c.pos); return !now || now.stateId === c.stateId })),
    TELEPORT_TIMEOUT_MS, () => `the dug/placed cells were not restored: ${JSON.stringify(cells.map(c => c.pos))}`)
}

// /give each bot what it lacks of the recorder's start kit (COMMON_ITEMS: 64 stone, diamond pickaxe,
// shovel and axe in hotbar slots 1-4 on an empty inventory); waits until every inventory has it.
const kitCount = (bot, item) => bot.inventory.items().filter(it => it.name === item).reduce((n, it) => n + it.count, 0)
const hasKit = (bot) => COMMON_ITEMS.every(([item, count]) => kitCount(bot, item) >= count)
async function giveKits () {
  bots.forEach((b, i) => {
    for (const [item, count] of COMMON_ITEMS) {
      const have = kitCount(b, item)
      if (have < count) b.chat(`/give ${cfg.names[i]} ${item} ${count - have}`)
    }
  })
  await waitFor(() => bots.every(hasKit), KIT_TIMEOUT_MS, () => `the bots did not get their start kit: ${JSON.stringify(
    bots.map(b => b.inventory.items().map(it => `${it.name} x${it.count} @${it.slot}`)))}`)
}

async function waitFor (cond, timeoutMs, what) {
  const deadline = Date.now() + timeoutMs
  while (!cond()) {
    if (Date.now() > deadline) throw new Error(`${what()} within ${timeoutMs} ms`)
    await sleep(50)
  }
}

async function handle (req) {
  try {
    if (req.op === 'step') startStep(req)
    else if (req.op === 'reset') await reset(req)
    else if (req.op === 'close') { reply({ op: 'closed' }); bots.forEach(b => b.quit()); setTimeout(() => process.exit(0), 200) } else throw new Error(`unknown op ${JSON.stringify(req.op)}`)
  } catch (err) {
    reply({ op: 'error', message: err && err.message ? err.message : String(err) })
  }
}

function serve () {
  let queue = Promise.resolve()
  const server = net.createServer((socket) => {
    if (client) { socket.end(JSON.stringify({ op: 'error', message: 'one client at a time' }) + '\n'); return }
    client = socket
    socket.setNoDelay(true)
    let buf = ''
    socket.on('data', (chunk) => {
      buf += chunk.toString('utf8')
      let nl
      while ((nl = buf.indexOf('\n')) >= 0) {
        const line = buf.slice(0, nl); buf = buf.slice(nl + 1)
        if (!line.trim()) continue
        let req
        try { req = JSON.parse(line) } catch (err) { reply({ op: 'error', message: `bad JSON: ${err.message}` }); continue }
        queue = queue.then(() => handle(req))
      }
    })
    socket.on('close', () => { client = null; process.exit(0) }) // the env is gone
    socket.on('error', () => {})
  })
  server.listen(0, '127.0.0.1', () => {
    process.stdout.write(JSON.stringify({ event: 'ready', port: server.address().port }) + '\n')
  })
}

async function main () {
  // One after the other: a player joining while the other is mid-login is not announced to it.
  for (const name of cfg.names) {
    const bot = common.makeBot(cfg, name, fail, { physicsEnabled: false }) // our clock runs the physics
    await new Promise((resolve) => bot.once('spawn', resolve))
    bots.push(bot)
    physics.push(common.makePhysicsStep(bot, name))
    acts.push({ dig: null, digCooldown: 0, useCooldown: 0, placed: [], mined: [], watchers: new Map() })
  }
  await giveKits() // on the empty inventory the kit fills hotbar slots 1-4 in order
  bots.forEach(b => views.push(common.makeView(cfg, b)))
  log(`${bots.length} bots spawned`)
  startClock()
  serve()
}

process.on('SIGTERM', () => process.exit(143))
process.on('SIGINT', () => process.exit(130))
process.stdin.on('end', () => process.exit(1)) // the supervisor died
process.stdin.resume()
main().catch(err => fail(err && err.stack ? err.stack : String(err)))
