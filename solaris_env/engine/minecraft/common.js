// Helpers shared by the recorder (record.js) and the env bridge (env_bridge.js): a deterministic RNG,
// angle helpers in Mineflayer's convention (yaw 0 = -Z, + = turn left; + pitch = up, radians), bot
// creation and the first-person view (prismarine-viewer on headless-gl, which needs an X display).
'use strict'
global.THREE = require('three')
global.Worker = require('worker_threads').Worker
const { performance } = require('perf_hooks')
const mineflayer = require('mineflayer')
const { Physics, PlayerState } = require('prismarine-physics')
const { createCanvas } = require('node-canvas-webgl/lib')
const { Viewer, WorldView } = require('prismarine-viewer/viewer')

const TICK_S = 0.05
const TICK_MS = 50
const MAX_CATCHUP_TICKS = 4 // due ticks run back to back at most (as mineflayer's physics loop)
const EYE = 1.62
const SNEAK_EYE = 1.27
const BURST_DT_MS = 25 // a physics tick less than this after the previous one is a catch-up tick
const CONTROL_KEYS = ['forward', 'back', 'left', 'right', 'jump', 'sprint', 'sneak']

// Deterministic RNG (mulberry32 over a string hash): the same text gives the same draws on every bot.
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
function wrapPi (a) { a = (a + Math.PI) % (2 * Math.PI); if (a < 0) a += 2 * Math.PI; return a - Math.PI }
function yawPitchTo (from, to) {
  const dx = to.x - from.x; const dy = to.y - from.y; const dz = to.z - from.z
  return [Math.atan2(-dx, -dz), Math.atan2(dy, Math.hypot(dx, dz))]
}

// A bot on cfg's server (knockback packets fixed up); kicks and errors call fail(message) (which should exit).
function makeBot (cfg, name, fail, options = {}) {
  const bot = mineflayer.createBot({ host: cfg.host, port: cfg.port, username: name, auth: 'offline', version: cfg.version, viewDistance: 'tiny', ...options })
  // flying-squid 1.12 writes entity_velocity (knockback) as {velocity: {x, y, z}} but mineflayer 4.25 reads
  // velocityX/Y/Z: without this a hit player's velocity, then position, become NaN.
  bot._client.prependListener('entity_velocity', (packet) => {
    if (packet.velocityX === undefined && packet.velocity) {
      Object.assign(packet, { velocityX: packet.velocity.x, velocityY: packet.velocity.y, velocityZ: packet.velocity.z })
    }
  })
  bot.on('kicked', (reason) => fail(`${name} kicked: ${JSON.stringify(reason)}`))
  bot.on('error', (err) => fail(`${name} error: ${err && err.stack ? err.stack : err}`))
  return bot
}

// The bot's first-person view at cfg.renderWidth x cfg.renderHeight with a cfg.fovDeg vertical FOV.
// render(pos, yaw, pitch, sneaking) sets the camera directly (no tween) and returns the RGBA pixels,
// bottom row first (gl.readPixels); the returned buffer is reused by the next call.
function makeView (cfg, bot) {
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
    worldView,
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

// Mineflayer's own physics step for one bot (prismarine-physics, the call of mineflayer's physics plugin, whose
// loop is switched off so that one clock ticks every bot): returns step(), which advances one tick once the bot's
// chunk is loaded and throws on a non-finite position (flying-squid packets have caused NaN positions).
function makePhysicsStep (bot, name) {
  const world = { getBlock: (pos) => bot.blockAt(pos, false) }
  const engine = Physics(bot.registry, world)
  return () => {
    if (bot.entity && bot.blockAt(bot.entity.position) != null) {
      engine.simulatePlayer(new PlayerState(bot, bot.controlState), world).apply(bot)
    }
    const p = bot.entity.position
    if (!Number.isFinite(p.x + p.y + p.z)) throw new Error(`${name}'s position is not finite: ${p}`)
  }
}

// One 20 Hz clock for all bots of a process (the recorder and the env bridge): ``tick(lateMs)`` runs once per
// due tick, at most ``maxCatchup`` back to back after a late timer (catch-up ticks); further behind, the clock
// skips ahead and ``onSkip(n)`` gets the number of ticks never played (the game ran slower than real time).
// The clock stops rescheduling itself once ``running()`` is false. Returns {t0, n}: n = due ticks so far.
function startLockstepClock ({ tick, onSkip, maxCatchup, running = () => true }) {
  const clock = { t0: performance.now(), n: 0 }
  function onClock () {
    let ran = 0
    while (performance.now() >= clock.t0 + (clock.n + 1) * TICK_MS) {
      if (ran === maxCatchup) {
        const skipped = Math.floor((performance.now() - clock.t0) / TICK_MS) - clock.n
        clock.n += skipped
        onSkip(skipped)
        break
      }
      clock.n++
      ran++
      tick(performance.now() - (clock.t0 + clock.n * TICK_MS))
    }
    if (running()) setTimeout(onClock, Math.max(0, clock.t0 + (clock.n + 1) * TICK_MS - performance.now()))
  }
  setTimeout(onClock, TICK_MS)
  return clock
}

module.exports = {
  TICK_S, TICK_MS, MAX_CATCHUP_TICKS, startLockstepClock, makePhysicsStep, EYE, SNEAK_EYE, BURST_DT_MS, CONTROL_KEYS, rngFrom, xzDist, uniform, wrapPi, yawPitchTo, makeBot, makeView
}
