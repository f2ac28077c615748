#!/usr/bin/env node
// A flying-squid Minecraft 1.20.1 server on 127.0.0.1, offline mode, flat world, everybody op (bots
// teleport themselves with /tp). Started and stopped by solaris_env/engine/minecraft/supervisor.py.
// Usage: node server.js '<json config>'   config: {port (0 = any free port), version, viewDistance, seed}
// Prints exactly one JSON line {"event":"ready","port":N} on stdout once it listens.
'use strict'
const mcServer = require('flying-squid')

const cfg = Object.assign({ port: 0, version: '1.20.1', viewDistance: 4, seed: 42 }, JSON.parse(process.argv[2] || '{}'))

const serv = mcServer.createMCServer({
  motd: 'solaris_env',
  port: cfg.port,
  host: '127.0.0.1',
  'max-players': 8,
  'online-mode': false,
  logging: false,
  gameMode: 0,
  difficulty: 0,
  generation: { name: 'superflat', options: { seed: cfg.seed, middleThickness: 3 } },
  kickTimeout: 30000,
  plugins: {},
  modpe: false,
  'view-distance': cfg.viewDistance,
  'player-list-text': { header: { text: '' }, footer: { text: '' } },
  'everybody-op': true,
  'max-entities': 16,
  version: cfg.version
})

// The reference gives every bot resistance 255 (docs/engine.md §9): hits knock back but never hurt, so
// pvp bouts never kill. flying-squid has no such effect; keep every player's health full instead.
serv.on('newPlayer', (player) => {
  const updateHealth = player.updateHealth
  if (typeof updateHealth === 'function') player.updateHealth = (health) => updateHealth(Math.max(health, 20))
  // Dug blocks drop nothing: the reference's player picks its drops up at once, and prismarine-viewer
  // draws item entities as magenta squares.
  player.on('dug', (data) => { data.dropBlock = false })
  // flying-squid 1.12 resends the login position once the client first moves or turns (login.js), which
  // undoes a /tp made right after spawning (a bot jumped back to its login spot mid-episode), and it
  // writes its byte-encoded yaw/pitch (1/256 turns) as degrees. Skip that resend; send the angles in degrees.
  player.sendSelfPosition = (newPosition) => {
    if (newPosition) return // only the login/changeworld resends pass a position
    const deg = (b) => b * 360 / 256
    player._client.write('position', {
      x: player.position.x, y: player.position.y, z: player.position.z,
      yaw: deg(player.yaw || 0), pitch: deg(player.pitch || 0), flags: 0x00, teleportId: 1
    })
  }
})

serv.on('listening', (port) => {
  process.stdout.write(JSON.stringify({ event: 'ready', port }) + '\n')
})
serv.on('error', (err) => {
  process.stderr.write(`server error: ${err && err.stack ? err.stack : err}\n`)
  process.exit(1)
})
const stop = () => { process.exit(0) }
process.on('SIGTERM', stop)
process.on('SIGINT', stop)
// The supervisor holds our stdin: when it dies, stdin closes and we exit (no orphans).
process.stdin.on('end', stop)
process.stdin.resume()
