// Episode choreographies of the real-Minecraft backend (docs/engine.md §5.3, §6), mirroring the voxel
// engine's Python bots (solaris_env/engine/bots/) so that both backends record comparable episodes:
// same phases, durations, distances, shared draws, eval bookkeeping and sneak signal.
//
// A choreography is a generator `EPISODES[type](ctx)` run by each bot; it yields one *intent* per
// 20 Hz physics tick, or a barrier. record.js applies the intent on that tick and records it:
//   {controls: {forward, back, left, right, jump, sprint, sneak}  held keys (missing = released)
//    yaw, pitch          absolute camera after this tick (mineflayer's unwrapped yaw; omitted = no turn)
//    hotbar: k           press hotbar key k (1..9)
//    place: {ref, face}  right-click the face `face` (Vec3 normal) of the block at `ref` (Vec3)
//    dig: {pos, face}    start digging the block at `pos` (mine stays true until the dig ends)
//    attack: entity      swing at a player entity}
//   {barrier: name}      wait until both bots yielded the barrier of this name
//
// ctx (built by record.js): bot, name, other (name), sortedNames, isLower, episode, tick, startTick,
// evalMetadata, shared() (identical draws on both bots), rng() (private draws), board (an object
// shared by both bots: barrier payloads and one-way posts), layout (from `planEpisode`), digging().
//
// Adaptations (same as the voxel engine's): pathfinder goals are straight-line steering (`goto`,
// `follow`); placing and digging aim at a face centre and need no line of sight; there are no mobs.
'use strict'
const { Vec3 } = require('vec3')

const TICKS_PER_S = 20
const EYE = 1.62
const SNEAK_EYE = 1.27
const LOOK_STEP_DEG = 0.15 // mineflayer's mouse grid
const PITCH_LIMIT = Math.PI / 2
const EVAL_DPS = 3 * 180 / Math.PI // 171.8873 deg/s = 3 rad/s, constant rate, no easing (as the voxel engine)
const CAMERA_DPS = 60 // lookAtSmooth
const BOT_LOOK_DPS = 90 // lookAtBot
const FAST_LOOK_DPS = 180 // randomized, hence clipped to <= 171 deg/s
const MAX_TURN_RAD = 3 / TICKS_PER_S // 0.15 rad: the per-tick camera cap of steering
const FOLLOW_TURN_RAD = (90 * Math.PI / 180) / TICKS_PER_S
const EPISODE_MIN_TICKS = 300
const REACH = 4.5
const MOVE_KEYS = ['forward', 'back', 'left', 'right']
const REVERSE = { forward: 'back', back: 'forward', left: 'right', right: 'left' }
const JUMP_PROB = 0.25
const WALK_MIN = 3; const WALK_MAX = 4
const WALK_TIMEOUT_S = 5
const ACTION_SLEEP = [0.2, 0.5]
const EYE_CONTACT_S = 1.5
const STUCK_TICKS = 10
const MOVING_SPEED = 0.02 // blocks/tick
const ATTACK_COOLDOWN_TICKS = 12 // a sword's 1.6 attacks/s, rounded
const FIGHT_CLOSE = 2.0
const FIGHT_RANGE = 3.0
const BODY_AIM_HEIGHT = 1.2
// Neighbour directions (support block -> placed cell), the block below first.
const FACE_NORMALS = [[0, 1, 0], [1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1], [0, -1, 0]]
// Items every bot gets before recording (docs/engine.md §5.1 step 4), in hotbar order; type-specific items follow.
const COMMON_ITEMS = [['stone', 64], ['diamond_pickaxe', 1], ['diamond_shovel', 1], ['diamond_axe', 1]]
const SWORDS = ['wooden_sword', 'stone_sword', 'iron_sword', 'golden_sword', 'diamond_sword', 'netherite_sword']

// ---------------------------------------------------------------------------------------------
// Math helpers
// ---------------------------------------------------------------------------------------------
const deg = (r) => r * 180 / Math.PI
const rad = (d) => d * Math.PI / 180
const ticks = (s) => Math.round(s * TICKS_PER_S)
const uniform = (rng, lo, hi) => lo + (hi - lo) * rng()
const randint = (rng, lo, hi) => lo + Math.floor(rng() * (hi - lo + 1)) // inclusive
const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x))
const xzDist = (a, b) => Math.hypot(a.x - b.x, a.z - b.z)
function wrapPi (a) { a = (a + Math.PI) % (2 * Math.PI); if (a < 0) a += 2 * Math.PI; return a - Math.PI }
function yawTo (from, to) { return Math.atan2(-(to.x - from.x), -(to.z - from.z)) }
function pitchTo (from, to) { return Math.atan2(to.y - from.y, Math.hypot(to.x - from.x, to.z - from.z)) }
function normal (rng) { // Box-Muller
  const u = Math.max(rng(), 1e-12); const v = rng()
  return Math.sqrt(-2 * Math.log(u)) * Math.cos(2 * Math.PI * v)
}
/** The reference's randomized look speed: dps x LogNormal(mean 1), clipped to [0.4 dps, 171]. */
function lognormalSpeed (rng, dps, volatility = 0.35) {
  const f = Math.exp(-volatility * volatility / 2 + volatility * normal(rng))
  return clamp(dps * f, 0.4 * dps, 171)
}
/** Per-tick angle steps (deg) summing to totalDeg quantised to 0.15 deg (the voxel engine's rotation_profile). */
function rotationProfile (totalDeg, speedDps, easing) {
  const q = Math.round(totalDeg / LOOK_STEP_DEG) * LOOK_STEP_DEG
  if (q === 0 || speedDps <= 0) return []
  if (!easing) {
    const step = speedDps / TICKS_PER_S
    const n = Math.ceil(Math.abs(q) / step - 1e-9)
    const steps = new Array(n - 1).fill(Math.sign(q) * step)
    return steps.concat([q - steps.reduce((a, b) => a + b, 0)])
  }
  const n = Math.max(1, Math.ceil(Math.abs(q) / (speedDps * 0.8) * TICKS_PER_S))
  const v = []; let sum = 0
  for (let i = 0; i < n; i++) {
    const u = (i + 0.5) / n
    v.push(Math.min(1, u / 0.2, (1 - u) / 0.2)); sum += v[i]
  }
  return v.map(x => x / sum * q)
}

// ---------------------------------------------------------------------------------------------
// World queries
// ---------------------------------------------------------------------------------------------
const me = (ctx) => ctx.bot.entity
const otherEntity = (ctx) => {
  const p = ctx.bot.players[ctx.other]
  if (!p || !p.entity) throw new Error(`${ctx.name} does not see ${ctx.other}`)
  return p.entity
}
const eyeOf = (e, sneaking = false) => e.position.offset(0, sneaking ? SNEAK_EYE : EYE, 0)
const isLower = (ctx) => ctx.isLower
function blockName (ctx, x, y, z) { const b = ctx.bot.blockAt(new Vec3(x, y, z)); return b ? b.name : 'unloaded' }
function isSolid (ctx, x, y, z) { const b = ctx.bot.blockAt(new Vec3(x, y, z)); return !!b && b.boundingBox === 'block' }
function feetCell (ctx) { const p = me(ctx).position; return [Math.floor(p.x), Math.floor(p.y + 0.01), Math.floor(p.z)] }
function hotbarSlotOf (ctx, item) {
  for (let s = 0; s < 9; s++) {
    const it = ctx.bot.inventory.slots[36 + s]
    if (it && it.name === item && it.count > 0) return s
  }
  return null
}
function blockedAhead (ctx) {
  const e = me(ctx)
  const ax = e.position.x - Math.sin(e.yaw) * 0.8; const az = e.position.z - Math.cos(e.yaw) * 0.8
  const x = Math.floor(ax); const y = Math.floor(e.position.y + 0.01); const z = Math.floor(az)
  return isSolid(ctx, x, y, z) && !isSolid(ctx, x, y + 1, z) && !isSolid(ctx, x, y + 2, z)
}

// ---------------------------------------------------------------------------------------------
// Primitives (generators; those that can fail return a bool)
// ---------------------------------------------------------------------------------------------
function * idle (ctx, n, controls = {}) { for (let i = 0; i < Math.max(0, Math.round(n)); i++) yield { controls } }
function * sleep (ctx, seconds) { yield * idle(ctx, ticks(seconds)) }
function * barrier (ctx, name, payload = {}) {
  (ctx.board[name] = ctx.board[name] || {})[ctx.name] = payload
  yield { barrier: name }
}
function payloadOf (ctx, name, who) { return (ctx.board[name] || {})[who] }
function post (ctx, name, payload = {}) { ctx.board[`post:${name}`] = { ...payload, sender: ctx.name } }
function received (ctx, name) { const m = ctx.board[`post:${name}`]; return m && m.sender !== ctx.name ? m : null }

/** Turn to (yaw, pitch) along the shortest arc at dps (constant rate, or eased), holding `controls`. */
function * look (ctx, yaw, pitch, dps, { easing = false, randomized = false, controls = {} } = {}) {
  if (randomized) dps = lognormalSpeed(ctx.rng, dps)
  pitch = clamp(pitch, -PITCH_LIMIT, PITCH_LIMIT)
  const y0 = me(ctx).yaw; const p0 = me(ctx).pitch
  const ys = rotationProfile(deg(wrapPi(yaw - y0)), dps, easing)
  const ps = rotationProfile(deg(pitch - p0), dps, easing)
  let cy = 0; let cp = 0
  for (let t = 0; t < Math.max(ys.length, ps.length); t++) {
    cy += t < ys.length ? ys[t] : 0; cp += t < ps.length ? ps[t] : 0
    yield { controls, yaw: y0 + rad(cy), pitch: clamp(p0 + rad(cp), -PITCH_LIMIT, PITCH_LIMIT) }
  }
}
/** Turn by dyaw radians (+ = left), any size, keeping the pitch. */
function * turn (ctx, dyaw, dps, { easing = false, controls = {} } = {}) {
  const y0 = me(ctx).yaw; const p0 = me(ctx).pitch
  let c = 0
  for (const s of rotationProfile(deg(dyaw), dps, easing)) { c += s; yield { controls, yaw: y0 + rad(c), pitch: p0 } }
}
function * lookAt (ctx, point, dps = EVAL_DPS, opts = {}) {
  const eye = eyeOf(me(ctx), !!(opts.controls && opts.controls.sneak))
  yield * look(ctx, yawTo(eye, point), pitchTo(eye, point), dps, opts)
}
/** lookAtSmooth: feet to feet (pitch ~0 on flat ground), eased and randomized by default. */
function * lookAtSmooth (ctx, feet, dps = CAMERA_DPS, { easing = true, randomized = true } = {}) {
  const p = me(ctx).position
  yield * look(ctx, yawTo(p, feet), pitchTo(p, feet), dps, { easing, randomized })
}
/** Eye contact: aim at the other player's head (lookAtBot). */
function * lookAtPlayer (ctx, dps = EVAL_DPS, opts = {}) { yield * lookAt(ctx, eyeOf(otherEntity(ctx)), dps, opts) }
function * eyeContact (ctx, seconds = EYE_CONTACT_S) { yield * lookAtPlayer(ctx); yield * sleep(ctx, seconds) }

/** One tick's camera toward (yaw, pitch): at most maxStep rad per axis, on the 0.15 deg grid. */
function turnStep (ctx, yaw, pitch, maxStep = MAX_TURN_RAD) {
  const q = rad(LOOK_STEP_DEG); const nMax = Math.floor(maxStep / q + 1e-9)
  const e = me(ctx)
  const ny = clamp(Math.round(wrapPi(yaw - e.yaw) / q), -nMax, nMax)
  const np = clamp(Math.round((clamp(pitch, -PITCH_LIMIT, PITCH_LIMIT) - e.pitch) / q), -nMax, nMax)
  return { yaw: e.yaw + ny * q, pitch: e.pitch + np * q }
}
function * select (ctx, item) {
  const slot = hotbarSlotOf(ctx, item)
  if (slot === null) throw new Error(`${ctx.name} has no ${item} in the hotbar`)
  if (slot !== ctx.bot.quickBarSlot) yield { controls: {}, hotbar: slot + 1 }
}
/** Hold a WASD key until displaced by `dist` blocks or timeout; jumps toggled 250 ms on/off with prob jumpProb. */
function * walk (ctx, key, dist, timeoutS = WALK_TIMEOUT_S, jumpProb = 0, extra = {}) {
  const start = me(ctx).position.clone()
  const jumping = ctx.rng() < jumpProb
  for (let t = 0; t < ticks(timeoutS); t++) {
    if (xzDist(me(ctx).position, start) >= dist) return true
    yield { controls: { [key]: true, jump: jumping && Math.floor(t / 5) % 2 === 0, ...extra } }
  }
  return false
}
function * walkBack (ctx, key, origin, tol = 1.0, timeoutS = WALK_TIMEOUT_S, jumpProb = 0) {
  const jumping = ctx.rng() < jumpProb
  for (let t = 0; t < ticks(timeoutS); t++) {
    if (xzDist(me(ctx).position, origin) <= tol) return true
    yield { controls: { [key]: true, jump: jumping && Math.floor(t / 5) % 2 === 0 } }
  }
  return false
}
/** One tick of walking toward `goal`: turn (<= 0.15 rad), forward when roughly facing it, jump steps. */
function steer (ctx, goal, dist, sprint, forceJump) {
  const e = me(ctx)
  const target = yawTo(e.position, goal)
  const fwd = Math.abs(wrapPi(target - e.yaw)) < rad(45)
  const jump = (fwd && e.onGround && blockedAhead(ctx)) || (forceJump && e.onGround) || !!e.isInWater
  return { controls: { forward: fwd, jump, sprint: sprint && fwd && dist > 3 }, ...turnStep(ctx, target, 0) }
}
/** Walk toward goal (x, z) until within radius or timeout (the pathfinder's GoalNear on open ground). */
function * goto (ctx, goal, radius = 1, timeoutS = 10, sprint = false) {
  const end = ctx.tick + ticks(timeoutS); let stuck = 0
  while (ctx.tick < end) {
    const e = me(ctx)
    const dist = xzDist(e.position, goal)
    if (dist <= radius) return true
    stuck = Math.hypot(e.velocity.x, e.velocity.z) > MOVING_SPEED ? 0 : stuck + 1
    yield steer(ctx, goal, dist, sprint, stuck > STUCK_TICKS)
  }
  return false
}
/** GoalFollow: re-aim at the other player every refreshTicks; inside radius stand and keep it in view. */
function * follow (ctx, radius, n, { sprint = false, refreshTicks = 1, until = null } = {}) {
  let goal = otherEntity(ctx).position.clone(); let stuck = 0
  for (let t = 0; t < n; t++) {
    if (until && until()) return true
    if (t % refreshTicks === 0) goal = otherEntity(ctx).position.clone()
    const e = me(ctx)
    const dist = xzDist(e.position, goal)
    if (dist <= radius) {
      const eye = eyeOf(e); const o = eyeOf(otherEntity(ctx))
      yield { controls: {}, ...turnStep(ctx, yawTo(eye, o), pitchTo(eye, o), FOLLOW_TURN_RAD) }
      continue
    }
    stuck = Math.hypot(e.velocity.x, e.velocity.z) > MOVING_SPEED ? 0 : stuck + 1
    yield steer(ctx, goal, dist, sprint, stuck > STUCK_TICKS)
  }
  return false
}
/** Keep the crosshair on the other player's head for n ticks (or until `until()`), at most dps. */
function * track (ctx, n, dps, until = null) {
  const step = Math.min(MAX_TURN_RAD, rad(dps) / TICKS_PER_S)
  for (let t = 0; t < n; t++) {
    if (until && until()) return true
    const eye = eyeOf(me(ctx)); const o = eyeOf(otherEntity(ctx))
    yield { controls: {}, ...turnStep(ctx, yawTo(eye, o), pitchTo(eye, o), step) }
  }
  return false
}
/** The eval signal (docs/engine.md §6.1): sneak 5 ticks, release, idle 25 ticks; sets startTick. */
function * sneakSignal (ctx) {
  yield * idle(ctx, 5, { sneak: true })
  yield * idle(ctx, 25)
  ctx.startTick = ctx.tick // the generator resumes on the tick whose intent comes next
}
function * padTo (ctx, n) {
  if (ctx.startTick === null) throw new Error('padTo before the sneak signal')
  yield * idle(ctx, ctx.startTick + n - ctx.tick)
}

// -- building and digging ---------------------------------------------------------------------
function supportFace (ctx, [x, y, z]) {
  for (const n of FACE_NORMALS) {
    const s = [x - n[0], y - n[1], z - n[2]]
    if (isSolid(ctx, ...s)) return { support: s, normal: n }
  }
  return null
}
function overlaps (entity, [x, y, z]) {
  const p = entity.position
  return p.x + 0.3 > x && p.x - 0.3 < x + 1 && p.z + 0.3 > z && p.z - 0.3 < z + 1 && p.y < y + 1 && p.y + 1.8 > y
}
/** Step straight away from a point (xz) until `dist` blocks from it, camera still. */
function * stepAway (ctx, point, dist = 1.2, timeoutS = 1.5) {
  for (let t = 0; t < ticks(timeoutS); t++) {
    const e = me(ctx)
    if (xzDist(e.position, point) >= dist) return true
    // the direction away from the point in the body frame (forward = -z rotated by yaw)
    const dx = e.position.x - point.x; const dz = e.position.z - point.z
    const fx = -Math.sin(e.yaw); const fz = -Math.cos(e.yaw); const lx = -Math.cos(e.yaw); const lz = Math.sin(e.yaw)
    const f = dx * fx + dz * fz; const l = dx * lx + dz * lz
    const n = Math.hypot(f, l) || 1
    yield { controls: { forward: f > 0.38 * n, back: f < -0.38 * n, left: l > 0.38 * n, right: l < -0.38 * n } }
  }
  return false
}
/** Place `item` at `cell` against a solid neighbour's face; true when the block stands there. */
function * placeAt (ctx, cell, item, { attempts = 3, approach = true, sneak = false, settleTicks = 0 } = {}) {
  const [x, y, z] = cell
  const centre = new Vec3(x + 0.5, y + 0.5, z + 0.5)
  for (let a = 0; a < attempts; a++) {
    if (blockName(ctx, x, y, z) === item) return true
    const sf = supportFace(ctx, cell)
    if (sf === null) return false
    yield * select(ctx, item)
    if (approach && eyeOf(me(ctx)).distanceTo(centre) > REACH - 0.8) yield * goto(ctx, centre, 2.5, 5)
    if (overlaps(me(ctx), cell)) yield * stepAway(ctx, centre)
    const [sx, sy, sz] = sf.support; const [nx, ny, nz] = sf.normal
    const face = new Vec3(sx + 0.5 + nx * 0.5, sy + 0.5 + ny * 0.5, sz + 0.5 + nz * 0.5)
    yield * lookAt(ctx, face, EVAL_DPS, { controls: { sneak } })
    yield * idle(ctx, settleTicks, { sneak })
    yield { controls: { sneak }, place: { ref: new Vec3(sx, sy, sz), face: new Vec3(nx, ny, nz) } }
    for (let t = 0; t < 6 && blockName(ctx, x, y, z) !== item; t++) yield { controls: { sneak } } // server round trip
  }
  return blockName(ctx, x, y, z) === item
}
/** Pillar up one block: look down, jump, and place `item` in the cell the feet just left. */
/** Jump and place `item` under the feet; a click the server rejects (it judged the feet against a stale
 * position) is retried, up to `attempts` jumps. */
function * placeBelow (ctx, item, pitch = -PITCH_LIMIT, timeoutS = 2, attempts = 3) {
  for (let a = 0; a < attempts; a++) if (yield * jumpPlaceOnce(ctx, item, pitch, timeoutS)) return true
  return false
}
function * jumpPlaceOnce (ctx, item, pitch, timeoutS) {
  const [x, y, z] = feetCell(ctx)
  if (!isSolid(ctx, x, y - 1, z) || isSolid(ctx, x, y + 2, z) || isSolid(ctx, x, y, z)) return false
  yield * select(ctx, item)
  yield * look(ctx, me(ctx).yaw, pitch, EVAL_DPS)
  let used = false; let clearTicks = 0
  for (let t = 0; t < ticks(timeoutS); t++) {
    if (blockName(ctx, x, y, z) === item) break
    // The server checks the feet against the last position mineflayer sent (up to a tick old): click on
    // the second tick with the feet out of the cell.
    clearTicks = me(ctx).position.y > y + 1 + 1e-6 ? clearTicks + 1 : 0
    const intent = { controls: { jump: me(ctx).onGround && !used } }
    if (clearTicks >= 2 && !used) { intent.place = { ref: new Vec3(x, y - 1, z), face: new Vec3(0, 1, 0) }; used = true }
    yield intent
  }
  for (let t = 0; t < 12 && !me(ctx).onGround; t++) yield { controls: {} }
  return blockName(ctx, x, y, z) === item
}
/** Look at the face of `cell` nearest the eye and dig it out (mine stays true meanwhile). */
function * dig (ctx, cell, timeoutS = 5) {
  const [x, y, z] = cell
  const centre = new Vec3(x + 0.5, y + 0.5, z + 0.5)
  if (blockName(ctx, x, y, z) === 'air') return true
  if (eyeOf(me(ctx)).distanceTo(centre) > REACH - 0.3) yield * goto(ctx, centre, 2.5, 5)
  if (hotbarSlotOf(ctx, 'diamond_pickaxe') !== null) yield * select(ctx, 'diamond_pickaxe')
  const eye = eyeOf(me(ctx))
  let best = null
  for (const n of FACE_NORMALS) { // an exposed face turned towards the eye
    if (isSolid(ctx, x + n[0], y + n[1], z + n[2])) continue
    const p = new Vec3(x + 0.5 + n[0] * 0.5, y + 0.5 + n[1] * 0.5, z + 0.5 + n[2] * 0.5)
    const facing = (eye.x - p.x) * n[0] + (eye.y - p.y) * n[1] + (eye.z - p.z) * n[2]
    if (facing > 0 && (best === null || eye.distanceTo(p) < best.d)) best = { d: eye.distanceTo(p), p, n }
  }
  const aim = best ? best.p : centre
  yield * lookAt(ctx, aim, EVAL_DPS)
  yield { controls: {}, dig: { pos: new Vec3(x, y, z), face: new Vec3(...(best ? best.n : [0, 1, 0])) } }
  for (let t = 0; t < ticks(timeoutS); t++) {
    if (blockName(ctx, x, y, z) === 'air' && !ctx.digging()) return true
    yield { controls: {} }
  }
  return blockName(ctx, x, y, z) === 'air'
}
/** mineflayer-pvp attack for n ticks: close in, keep the crosshair on the body, swing when in range and cooled down. */
function * fight (ctx, n, close = FIGHT_CLOSE) {
  let cooldown = 0
  for (let t = 0; t < n; t++) {
    cooldown = Math.max(0, cooldown - 1)
    const e = me(ctx); const o = otherEntity(ctx)
    const eye = eyeOf(e); const aim = o.position.offset(0, BODY_AIM_HEIGHT, 0)
    const step = turnStep(ctx, yawTo(eye, aim), pitchTo(eye, aim))
    const dist = xzDist(e.position, o.position)
    const facing = Math.abs(wrapPi(yawTo(e.position, o.position) - e.yaw)) < rad(45)
    const fwd = dist > close && facing
    const jump = (fwd && e.onGround && blockedAhead(ctx)) || !!e.isInWater
    const onTarget = Math.abs(wrapPi(yawTo(eye, aim) - e.yaw)) < rad(12) && Math.abs(pitchTo(eye, aim) - e.pitch) < rad(25)
    const swing = onTarget && eye.distanceTo(aim) <= FIGHT_RANGE && cooldown === 0
    if (swing) { cooldown = ATTACK_COOLDOWN_TICKS; yield { controls: { forward: fwd, jump }, attack: o } } else yield { controls: { forward: fwd, jump }, ...step }
  }
}
function * randomWalk (ctx, dist) {
  yield * sleep(ctx, uniform(ctx.rng, ...ACTION_SLEEP))
  const key = MOVE_KEYS[Math.floor(ctx.rng() * 4)]
  const start = me(ctx).position.clone()
  yield * walk(ctx, key, dist, WALK_TIMEOUT_S, JUMP_PROB)
  yield * walkBack(ctx, REVERSE[key], start, 1.0, WALK_TIMEOUT_S, JUMP_PROB)
}
const decidePrimary = (ctx) => ctx.sortedNames[Math.floor(ctx.shared() * 2)] === ctx.name

// ---------------------------------------------------------------------------------------------
// Training types (docs/engine.md §5.3)
// ---------------------------------------------------------------------------------------------
function * walkLook (ctx) {
  for (let it = 0; it < 3; it++) {
    yield * barrier(ctx, `walkLook_${it}`, { pos: me(ctx).position.clone() })
    const actionCount = 2 + Math.floor(ctx.shared() * 3)
    const mode = ['both_bots_walk', 'lower_name_walks', 'bigger_name_walks'][Math.floor(ctx.shared() * 3)]
    yield * lookAtSmooth(ctx, payloadOf(ctx, `walkLook_${it}`, ctx.other).pos)
    const walks = mode === 'both_bots_walk' || ((mode === 'lower_name_walks') === isLower(ctx))
    if (walks) for (let k = 0; k < actionCount; k++) yield * randomWalk(ctx, uniform(ctx.rng, WALK_MIN, WALK_MAX))
  }
}

function * walkLookingAway (ctx) {
  const yaw0 = me(ctx).yaw; const pitch0 = me(ctx).pitch
  const away = yaw0 + Math.PI + rad(uniform(ctx.rng, -90, 90))
  yield * look(ctx, away, pitch0, CAMERA_DPS, { easing: true, randomized: true })
  yield * sleep(ctx, uniform(ctx.rng, ...ACTION_SLEEP))
  const key = MOVE_KEYS[Math.floor(ctx.rng() * 4)]
  const start = me(ctx).position.clone()
  yield * walk(ctx, key, uniform(ctx.rng, WALK_MIN, WALK_MAX), WALK_TIMEOUT_S, JUMP_PROB)
  let backKey = REVERSE[key]
  if (ctx.rng() < 0.5) { yield * turn(ctx, Math.PI, CAMERA_DPS, { easing: true }); backKey = key }
  yield * walkBack(ctx, backKey, start, 1.0, WALK_TIMEOUT_S, JUMP_PROB)
  yield * look(ctx, yaw0, pitch0, CAMERA_DPS, { easing: true, randomized: true })
}
function * walkLookAway (ctx) {
  for (let it = 0; it < 3; it++) {
    const name = `walkLookAway_${it}`
    yield * barrier(ctx, name, { pos: me(ctx).position.clone() })
    const lowerWalks = Math.floor(ctx.shared() * 2) === 0
    yield * lookAtSmooth(ctx, payloadOf(ctx, name, ctx.other).pos)
    if (lowerWalks === isLower(ctx)) yield * walkLookingAway(ctx)
  }
}

function * straightLineWalk (ctx) {
  yield * barrier(ctx, 'straightLineWalk')
  const lowerWalks = Math.floor(ctx.shared() * 2) === 0
  if (lowerWalks === isLower(ctx)) {
    const p = me(ctx).position; const o = otherEntity(ctx).position
    const n = Math.hypot(o.x - p.x, o.z - p.z) || 1
    const beyond = randint(ctx.rng, 4, 8)
    const goal = new Vec3(o.x + (o.x - p.x) / n * beyond, o.y, o.z + (o.z - p.z) / n * beyond)
    const sprint = ctx.rng() < 0.5
    yield * goto(ctx, goal, 1.0, 20, sprint)
    post(ctx, 'straightLineWalk_arrived')
    yield * lookAt(ctx, eyeOf(otherEntity(ctx)), FAST_LOOK_DPS, { randomized: true })
  } else {
    yield * track(ctx, ticks(20), BOT_LOOK_DPS, () => received(ctx, 'straightLineWalk_arrived') !== null)
  }
}

function * chase (ctx) {
  yield * barrier(ctx, 'chase')
  const chaser = decidePrimary(ctx)
  const n = ticks((5000 + Math.floor(ctx.shared() * 10001)) / 1000)
  if (chaser) { yield * follow(ctx, 3, n, { sprint: true, refreshTicks: ticks(1) }); return }
  const end = ctx.tick + n
  while (ctx.tick < end) { // GoalNear(A + 100 * normalize(A - chaser), 2) for the whole duration
    const p = me(ctx).position; const o = otherEntity(ctx).position
    const d = Math.hypot(p.x - o.x, p.z - o.z) || 1
    const goal = new Vec3(p.x + (p.x - o.x) / d * 100, p.y, p.z + (p.z - o.z) / d * 100)
    yield * goto(ctx, goal, 2, (end - ctx.tick) / TICKS_PER_S, true)
  }
}

function * orbit (ctx) {
  yield * barrier(ctx, 'orbit', { pos: me(ctx).position.clone() })
  const other = payloadOf(ctx, 'orbit', ctx.other).pos
  const mine = me(ctx).position.clone()
  const cx = (mine.x + other.x) / 2; const cz = (mine.z + other.z) / 2
  const radius = Math.hypot(mine.x - other.x, mine.z - other.z) / 2
  const angle0 = Math.atan2(mine.z - cz, mine.x - cx)
  for (let k = 1; k <= 8; k++) {
    const a = angle0 + k * 2 * Math.PI / 8
    yield * goto(ctx, new Vec3(cx + radius * Math.cos(a), mine.y, cz + radius * Math.sin(a)), 1.5, 5, true)
    yield * lookAtPlayer(ctx, BOT_LOOK_DPS)
    yield * sleep(ctx, 1.0)
  }
}

function * pvp (ctx) {
  yield * barrier(ctx, 'pvp')
  const n = ticks((10000 + Math.floor(ctx.shared() * 5001)) / 1000)
  yield * lookAt(ctx, eyeOf(otherEntity(ctx)), FAST_LOOK_DPS, { randomized: true })
  yield * sleep(ctx, 0.5)
  yield * select(ctx, ctx.layout.swords[ctx.name])
  yield * sleep(ctx, 0.5)
  yield * fight(ctx, n)
}

const STRUCTURES = ['wall', 'tower', 'platform']
const STRUCTURE_BLOCKS = ['stone', 'cobblestone', 'oak_planks', 'bricks']
function towardPartner (mine, other) {
  const dx = other.x - mine.x; const dz = other.z - mine.z
  return Math.abs(dx) >= Math.abs(dz) ? [dx >= 0 ? 1 : -1, 0] : [0, dz >= 0 ? 1 : -1]
}
function spiral (w, d) { // local (x, z) cells ring by ring from the edge to the centre
  const order = []; let x0 = 0; let z0 = 0; let x1 = w - 1; let z1 = d - 1
  while (x0 <= x1 && z0 <= z1) {
    for (let x = x0; x <= x1; x++) order.push([x, z0])
    for (let z = z0 + 1; z <= z1; z++) order.push([x1, z])
    if (z1 > z0) for (let x = x1 - 1; x >= x0; x--) order.push([x, z1])
    if (x1 > x0) for (let z = z1 - 1; z > z0; z--) order.push([x0, z])
    x0++; z0++; x1--; z1--
  }
  return order
}
function structureCells (ctx, kind, mine, other) {
  const x0 = Math.floor(mine.x); const y0 = Math.floor(mine.y + 0.01); const z0 = Math.floor(mine.z)
  const [sx, sz] = towardPartner(mine, other)
  const bx = x0 + 2 * sx; const bz = z0 + 2 * sz
  if (kind === 'wall') { // 5 x 2 across the line to the partner, bottom-up, left to right
    const ax = Math.abs(sz); const az = Math.abs(sx); const cells = []
    for (let j = 0; j < 2; j++) for (let i = -2; i <= 2; i++) cells.push([bx + i * ax, y0 + j, bz + i * az])
    return cells
  }
  if (kind === 'tower') return [[bx, y0, bz], [bx, y0 + 1, bz]]
  const ox = Math.floor((mine.x + other.x) / 2) - 2; const oz = Math.floor((mine.z + other.z) / 2) - 2
  const oy = Math.floor(Math.max(mine.y, other.y) + 0.01)
  const west = Math.floor(mine.x) !== Math.floor(other.x) ? mine.x < other.x : isLower(ctx)
  return spiral(4, 4).filter(([lx]) => (lx <= 2) === west).map(([lx, lz]) => [ox + lx, oy, oz + lz])
}
function * buildCells (ctx, cells, item, pauseS) {
  let pending = cells.filter(c => !isSolid(ctx, ...c))
  const attempted = pending.length
  for (let pass = 0; pass < 3 && pending.length; pass++) {
    const left = []
    for (const c of pending) {
      if (yield * placeAt(ctx, c, item, { attempts: 2 })) yield * sleep(ctx, pauseS)
      else left.push(c)
    }
    if (left.length === pending.length) break
    pending = left
  }
  return [attempted, pending.filter(c => blockName(ctx, ...c) !== item).length]
}
function checkBuild (name, attempted, failed) {
  if (attempted && failed / attempted > 0.5) throw new Error(`${name}: ${failed}/${attempted} placements failed`)
}
function * buildStructure (ctx) {
  yield * barrier(ctx, 'buildStructure', { pos: me(ctx).position.clone() })
  const kind = STRUCTURES[Math.floor(ctx.shared() * STRUCTURES.length)]
  const item = STRUCTURE_BLOCKS[Math.floor(ctx.shared() * STRUCTURE_BLOCKS.length)]
  const other = payloadOf(ctx, 'buildStructure', ctx.other).pos
  yield * eyeContact(ctx)
  const [attempted, failed] = yield * buildCells(ctx, structureCells(ctx, kind, me(ctx).position.clone(), other), item, 0.3)
  checkBuild('buildStructure', attempted, failed)
  ctx.summary = { structure: kind, block: item, attempted, failed }
  yield * eyeContact(ctx)
}

function * buildTower (ctx) {
  yield * barrier(ctx, 'buildTower')
  const height = 8 + Math.floor(ctx.shared() * 5)
  yield * eyeContact(ctx)
  let built = 0
  for (let k = 0; k < height; k++) {
    if (!(yield * placeBelow(ctx, 'oak_planks', -1.45))) break
    built++
    yield * sleep(ctx, 0.2)
  }
  ctx.summary = { height, built }
  yield * eyeContact(ctx)
}

function * mine (ctx) {
  yield * barrier(ctx, 'mine')
  yield * eyeContact(ctx)
  yield * select(ctx, 'diamond_pickaxe')
  yield * look(ctx, me(ctx).yaw, -PITCH_LIMIT, EVAL_DPS)
  yield * sleep(ctx, 0.5)
  const [x, y, z] = feetCell(ctx)
  const dug = yield * dig(ctx, [x, y - 1, z])
  yield * sleep(ctx, 0.8)
  if (!dug || me(ctx).position.y > y - 0.5) throw new Error('mine: digging down failed')
  yield * barrier(ctx, 'mine_underground', { pos: me(ctx).position.clone() })
  const other = payloadOf(ctx, 'mine_underground', ctx.other).pos
  const p = me(ctx).position
  const goal = new Vec3(Math.floor((p.x + other.x) / 2) + 0.5, Math.floor((p.y + other.y) / 2 + 0.01) - 1,
    Math.floor((p.z + other.z) / 2) + 0.5)
  ctx.summary = { reached: yield * tunnelTo(ctx, goal, 1.6, 60) }
  yield * eyeContact(ctx)
}
/** Dig a 1x2 tunnel toward goal (feet), a cardinal step at a time, one block down per step while it is lower. */
function * tunnelTo (ctx, goal, radius, timeoutS) {
  const end = ctx.tick + ticks(timeoutS)
  while (ctx.tick < end) {
    const p = me(ctx).position
    if (p.distanceTo(goal) <= radius) return true
    const [cx, cy, cz] = feetCell(ctx)
    const dx = goal.x - (cx + 0.5); const dz = goal.z - (cz + 0.5)
    const down = goal.y < cy - 0.5
    if (Math.max(Math.abs(dx), Math.abs(dz)) < 0.5) {
      if (!down || !(yield * dig(ctx, [cx, cy - 1, cz]))) return false
      yield * idle(ctx, 12)
      continue
    }
    const [sx, sz] = Math.abs(dx) >= Math.abs(dz) ? [Math.sign(dx), 0] : [0, Math.sign(dz)]
    const nx = cx + sx; const nz = cz + sz
    for (let yy = cy + 1; yy >= cy - (down ? 1 : 0); yy--) {
      if (isSolid(ctx, nx, yy, nz) && !(yield * dig(ctx, [nx, yy, nz]))) return false
    }
    yield * nudgeTo(ctx, new Vec3(nx + 0.5, 0, nz + 0.5), 1.5)
  }
  return false
}
/** Step to a point (x, z) with WASD and no camera motion; jumps when stuck. */
function * nudgeTo (ctx, point, timeoutS = 2, tol = 0.15) {
  let stuck = 0
  for (let t = 0; t < ticks(timeoutS); t++) {
    const e = me(ctx)
    const dx = point.x - e.position.x; const dz = point.z - e.position.z
    if (Math.hypot(dx, dz) <= tol) return true
    stuck = Math.hypot(e.velocity.x, e.velocity.z) > MOVING_SPEED ? 0 : stuck + 1
    const f = dx * -Math.sin(e.yaw) + dz * -Math.cos(e.yaw); const l = dx * -Math.cos(e.yaw) + dz * Math.sin(e.yaw)
    const h = tol / 2
    yield { controls: { forward: f > h, back: f < -h, left: l > h, right: l < -h, jump: e.onGround && stuck > 3 } }
  }
  return false
}

const PAM_BLOCKS = ['stone', 'oak_planks', 'bricks', 'dirt', 'smooth_sandstone']
function pamCells (ctx) {
  const count = randint(ctx.rng, 1, 5)
  const pick = ctx.rng() < 0.5 ? 1 : -1
  const offsets = { 1: [0], 2: [0, pick], 3: [-1, 0, 1], 4: [-1, 0, 1, 2 * pick], 5: [-2, -1, 0, 1, 2] }[count]
  const { centre: [x, y, z], obs } = ctx.layout
  const [ax, az] = obs === 'x' ? [0, 1] : [1, 0] // the activity axis is perpendicular to the observation axis
  return offsets.map(k => [x + k * ax, y, z + k * az])
}
function * placeAndMine (ctx) {
  yield * barrier(ctx, 'placeAndMine')
  const rounds = 7 + Math.floor(ctx.shared() * 4)
  const builder = ctx.layout.builder === ctx.name
  yield * lookAtPlayer(ctx, BOT_LOOK_DPS)
  yield * sleep(ctx, 1.0)
  let placedTotal = 0; let minedTotal = 0
  for (let r = 0; r < rounds; r++) {
    yield * barrier(ctx, `placeAndMine_build_${r}`)
    const placed = []
    if (builder) {
      const item = PAM_BLOCKS[Math.floor(ctx.rng() * PAM_BLOCKS.length)]
      for (const c of pamCells(ctx)) {
        if (yield * placeAt(ctx, c, item, { attempts: 3, approach: false })) placed.push(c)
        yield * sleep(ctx, uniform(ctx.rng, 0.4, 0.8))
      }
      placedTotal += placed.length
      yield * lookAtPlayer(ctx, BOT_LOOK_DPS)
      yield * sleep(ctx, 0.5 + uniform(ctx.rng, 0.5, 1.0))
    }
    yield * barrier(ctx, `placeAndMine_mine_${r}`, { cells: placed })
    if (!builder) {
      yield * select(ctx, 'diamond_pickaxe')
      yield * lookAtPlayer(ctx, BOT_LOOK_DPS)
      for (const c of payloadOf(ctx, `placeAndMine_mine_${r}`, ctx.other).cells) {
        if (yield * dig(ctx, c)) minedTotal++
        yield * sleep(ctx, uniform(ctx.rng, 0.4, 0.8))
      }
      yield * lookAtPlayer(ctx, BOT_LOOK_DPS)
      yield * sleep(ctx, 0.5 + uniform(ctx.rng, 0.5, 1.0))
    }
  }
  ctx.summary = { rounds, placed: placedTotal, mined: minedTotal }
}

// ---------------------------------------------------------------------------------------------
// Eval types (docs/engine.md §6): look at each other, barrier, the actor(s) sneak, act, pad to 300 ticks
// ---------------------------------------------------------------------------------------------
function * lookAtEachOther (ctx, phase, dps = EVAL_DPS) {
  yield * barrier(ctx, `${phase}_phase`, { pos: me(ctx).position.clone() })
  yield * lookAtSmooth(ctx, otherEntity(ctx).position, dps, { easing: false, randomized: false })
  yield * barrier(ctx, `${phase}_signal`)
}
const turnTo = (ctx, yaw, pitch) => look(ctx, yaw, pitch, EVAL_DPS)

function * rotationEval (ctx) {
  yield * lookAtEachOther(ctx, 'rotationEval')
  const kase = ctx.episode % 6
  const rotator = ctx.sortedNames[kase < 3 ? 0 : 1]
  const degrees = [40, -40, 180][kase % 3]
  ctx.evalMetadata = { bots_chosen: [rotator], rotation_degrees: degrees, camera_speed_degrees_per_sec: EVAL_DPS, case_num: kase }
  if (ctx.name !== rotator) return
  yield * sneakSignal(ctx)
  yield * turn(ctx, rad(degrees), EVAL_DPS)
  yield * padTo(ctx, EPISODE_MIN_TICKS)
}

function * translationEval (ctx) {
  const [lower, bigger] = ctx.sortedNames
  const aligner = ctx.shared() < 0.5 ? lower : bigger
  ctx.shared() // the reference draws its run-action count (always 1) here
  if (ctx.name === aligner) { // share the other's x (if |dx| < |dz|) or z, then wait 5 ticks
    const p = me(ctx).position; const o = otherEntity(ctx).position
    const goal = Math.abs(o.x - p.x) < Math.abs(o.z - p.z) ? new Vec3(o.x, p.y, p.z) : new Vec3(p.x, p.y, o.z)
    yield * goto(ctx, goal, 0.5, 10, true)
    yield * idle(ctx, 5)
  }
  yield * lookAtEachOther(ctx, 'translationEval')
  const mode = ['lower_name_walks', 'bigger_name_walks'][ctx.episode % 2]
  const walker = ctx.sortedNames[ctx.episode % 2]
  ctx.evalMetadata = { bots_chosen: [walker], mode, camera_speed_degrees_per_sec: EVAL_DPS, min_run_actions: 1, max_run_actions: 1 }
  if (ctx.name !== walker) return
  yield * sneakSignal(ctx)
  yield * sleep(ctx, uniform(ctx.rng, 0.2, 0.5))
  const key = MOVE_KEYS[Math.floor(ctx.rng() * 4)]
  const start = me(ctx).position.clone()
  yield * walk(ctx, key, uniform(ctx.rng, 6, 9), 5)
  yield * walkBack(ctx, REVERSE[key], start, 1.0, 5)
  yield * padTo(ctx, EPISODE_MIN_TICKS)
}

function * lookAway (ctx, mode, actors) {
  const dir = ctx.shared() < 0.5 ? -1 : 1
  const offset = 90 * dir + ctx.shared() * 45 - 22.5
  ctx.evalMetadata = { bots_chosen: actors, mode, camera_speed_degrees_per_sec: EVAL_DPS, look_away_offset_deg: offset, look_away_direction: dir, freeze_ticks: 60 }
  if (!actors.includes(ctx.name)) return
  yield * sneakSignal(ctx)
  const yaw0 = me(ctx).yaw; const pitch0 = me(ctx).pitch
  yield * turnTo(ctx, yaw0 + Math.PI + rad(offset), pitch0)
  yield * idle(ctx, 60)
  yield * turnTo(ctx, yaw0, pitch0)
  yield * padTo(ctx, EPISODE_MIN_TICKS)
}
function * oneLooksAwayEval (ctx) {
  yield * lookAtEachOther(ctx, 'oneLooksAwayEval')
  yield * lookAway(ctx, ['lower_name_looks_away', 'bigger_name_looks_away'][ctx.episode % 2], [ctx.sortedNames[ctx.episode % 2]])
}
function * bothLookAwayEval (ctx) {
  yield * lookAtEachOther(ctx, 'bothLookAwayEval')
  yield * lookAway(ctx, 'both_look_away', ctx.sortedNames)
}

const LOOK_SETTLE_TICKS = 18 // structureEval: the reference waits this long after looking before it clicks
const STRUCTURE_OFFSETS = {
  wall_2x2: [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]],
  wall_4x1: [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]],
  tower_2x1: [[0, 0, 0], [0, 1, 0]]
}
function * structureEval (ctx) {
  const names = ctx.sortedNames
  yield * lookAtEachOther(ctx, 'structureEval')
  const roleMode = ['alpha_builds', 'bravo_builds'][Math.floor(ctx.shared() * 2)]
  const builder = roleMode === 'alpha_builds' ? names[0] : names[1]
  const observer = builder === names[0] ? names[1] : names[0]
  const isBuilder = ctx.name === builder
  const bpos = payloadOf(ctx, 'structureEval_phase', builder).pos
  const base = [Math.floor(bpos.x) + 1, Math.floor(bpos.y + 0.01), Math.floor(bpos.z)]
  if (isBuilder) {
    yield * select(ctx, 'stone')
    yield * idle(ctx, 15)
    yield * sneakSignal(ctx)
    yield * idle(ctx, 10)
    yield * lookAtPlayer(ctx)
  } else yield * idle(ctx, 25)
  yield * idle(ctx, 4)
  const structure = Object.keys(STRUCTURE_OFFSETS)[Math.floor(ctx.shared() * 3)]
  const blockType = ['stone'][Math.floor(ctx.shared() * 1)]
  ctx.evalMetadata = { structure_type: structure, block_type: blockType, builder_bot: builder, observer_bot: observer, role_assignment_mode: roleMode }
  const cells = STRUCTURE_OFFSETS[structure].map(([dx, dy, dz]) => [base[0] + dx, base[1] + dy, base[2] + dz])
  if (isBuilder) {
    const p = me(ctx).position
    const order = [...cells].sort((a, b) => a[1] - b[1] ||
      xzDist(new Vec3(b[0] + 0.5, 0, b[2] + 0.5), p) - xzDist(new Vec3(a[0] + 0.5, 0, a[2] + 0.5), p) || a[0] - b[0])
    for (const c of order) { // stand one block in front (-z) of the cell, look at the top of its support, click
      yield * nudgeTo(ctx, new Vec3(c[0] + 0.5, 0, c[2] - 1.0), 3)
      yield * placeAt(ctx, c, 'stone', { attempts: 5, approach: false, sneak: true, settleTicks: LOOK_SETTLE_TICKS })
      yield * idle(ctx, 4)
    }
  } else yield * idle(ctx, cells.length * 4)
  const length = Math.max(...STRUCTURE_OFFSETS[structure].map(o => o[0])) + 1
  const centreX = base[0] + length / 2
  const front = new Vec3(centreX + (isBuilder ? 1 : -1), base[1], base[2] - 6)
  yield * goto(ctx, front, 1.0, 10)
  const view = new Vec3(centreX, base[1], base[2])
  const p = me(ctx).position
  yield * turnTo(ctx, yawTo(p, view), pitchTo(p, view))
  yield * idle(ctx, 4)
  if (isBuilder) yield * padTo(ctx, EPISODE_MIN_TICKS)
}

function * turnToLook (ctx, sameSide, phase) {
  yield * barrier(ctx, `${phase}_phase`, { pos: me(ctx).position.clone() })
  yield * idle(ctx, 2)
  yield * lookAtSmooth(ctx, otherEntity(ctx).position, 90, { easing: false, randomized: false })
  yield * barrier(ctx, `${phase}_signal`)
  yield * sneakSignal(ctx)
  const m = me(ctx).position.clone(); const o = otherEntity(ctx).position
  let nx = o.x - m.x; let nz = o.z - m.z; const n = Math.hypot(nx, nz) || 1
  nx /= n; nz /= n
  const dir = sameSide ? (isLower(ctx) ? 1 : -1) : 1
  const side = { x: -nz * dir + 0, z: nx * dir + 0 }
  ctx.evalMetadata = { camera_speed_degrees_per_sec: EVAL_DPS, side_vector: side, dir }
  const face = m.offset(side.x, 0, side.z)
  yield * turnTo(ctx, yawTo(m, face), pitchTo(m, face))
  yield * padTo(ctx, EPISODE_MIN_TICKS)
}
function * turnToLookEval (ctx) { yield * turnToLook(ctx, true, 'turnToLookEval') }
function * turnToLookOppositeEval (ctx) { yield * turnToLook(ctx, false, 'turnToLookOppositeEval') }

// A short smoke type for tests and benchmarks (not a paper type): both bots turn to each other and hold still.
function * lookAtEachOtherSmoke (ctx) {
  yield * barrier(ctx, 'lookAtEachOther')
  yield * lookAtSmooth(ctx, otherEntity(ctx).position, EVAL_DPS, { easing: false, randomized: false })
  yield * idle(ctx, Math.max(0, (ctx.smokeTicks || 200) - ctx.tick))
}

const EPISODES = {
  walkLook, walkLookAway, straightLineWalk, chase, orbit, pvp, buildStructure, buildTower, mine, placeAndMine,
  rotationEval, translationEval, oneLooksAwayEval, bothLookAwayEval, structureEval, turnToLookEval,
  turnToLookOppositeEval, lookAtEachOther: lookAtEachOtherSmoke
}
const EVAL_TYPES = new Set(['rotationEval', 'translationEval', 'oneLooksAwayEval', 'bothLookAwayEval', 'structureEval',
  'turnToLookEval', 'turnToLookOppositeEval'])

// ---------------------------------------------------------------------------------------------
// Spawn plan and items (before recording)
// ---------------------------------------------------------------------------------------------
/**
 * Where the two bots stand and what they hold, for one episode.
 * @param {string} type episode type
 * @param {{names: string[], spawnMin: number, spawnMax: number}} cfg
 * @param {() => number} rng a deterministic draw for this episode's placement
 * @returns {{spots: number[][], items: Object<string, Array>, layout: object}} spots: [x, z] per name
 *   (relative to the episode's centre), items: per name the [item, count] list in hotbar order.
 */
function planEpisode (type, cfg, rng) {
  const names = cfg.names; const sorted = [...names].sort()
  const items = Object.fromEntries(names.map(n => [n, [...COMMON_ITEMS]]))
  const layout = {}
  let spots
  if (type === 'placeAndMine' || type === 'turnToLookEval' || type === 'turnToLookOppositeEval') {
    // two bots 4 blocks apart on one axis (placeAndMine: builder and miner either side of the centre)
    const axisX = rng() < 0.5; const side = rng() < 0.5 ? 1 : -1
    const first = type === 'placeAndMine' ? sorted[Math.floor(rng() * 2)] : sorted[0]
    layout.centre = [0, 0, 0]; layout.obs = axisX ? 'x' : 'z'; layout.builder = first
    spots = names.map(n => {
      const s = (n === first ? 2 : -2) * (type === 'placeAndMine' ? side : -1)
      return axisX ? [s, 0] : [0, s]
    })
  } else {
    const d = uniform(rng, cfg.spawnMin, cfg.spawnMax); const ang = rng() * 2 * Math.PI
    spots = [[0, 0], [Math.round(d * Math.cos(ang)), Math.round(d * Math.sin(ang))]]
  }
  if (type === 'pvp') { // a random sword each (the reference's Math.random)
    layout.swords = {}
    for (const n of names) { layout.swords[n] = SWORDS[Math.floor(rng() * SWORDS.length)]; items[n].push([layout.swords[n], 1]) }
  }
  if (type === 'buildStructure') for (const n of names) items[n].push(['cobblestone', 64], ['oak_planks', 64], ['bricks', 64])
  if (type === 'buildTower') for (const n of names) items[n].push(['oak_planks', 64])
  if (type === 'placeAndMine') for (const n of names) items[n].push(['oak_planks', 64], ['bricks', 64], ['dirt', 64], ['smooth_sandstone', 64])
  if (type === 'mine') for (const n of names) items[n].push(['torch', 64])
  return { spots, items, layout }
}

module.exports = { EPISODES, EVAL_TYPES, COMMON_ITEMS, planEpisode, rotationProfile, yawTo, pitchTo, wrapPi, EYE, SNEAK_EYE, EPISODE_MIN_TICKS }
