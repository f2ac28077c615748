#!/usr/bin/env node
// Applied by `solaris-engine setup-minecraft` after `npm ci` (idempotent).
//
// flying-squid 1.12.0 bug: `serv._sendPlayerList(player)` writes the player list only to the *other*
// players (`toPlayer._writeOthers`), so a player who joins is never told about the players already
// online and mineflayer ignores their spawn packets (unknown UUID): the second bot never sees the
// first. The fix sends the list to every player, the joining one included (`serv._writeAll`).
'use strict'
const fs = require('fs')
const path = require('path')

const file = path.join(__dirname, 'node_modules', 'flying-squid', 'src', 'lib', 'plugins', 'login.js')
const BUGGY = "toPlayer._writeOthers('player_info'"
const FIXED = "serv._writeAll('player_info'"

if (!fs.existsSync(file)) {
  console.error(`patch-flying-squid: ${file} not found (run npm ci first)`)
  process.exit(2)
}
const src = fs.readFileSync(file, 'utf8')
const n = src.split(BUGGY).length - 1
if (n === 0) {
  if (src.includes(FIXED)) {
    console.log('patch-flying-squid: already applied')
    process.exit(0)
  }
  console.error('patch-flying-squid: neither the buggy nor the fixed line found (unexpected flying-squid version)')
  process.exit(3)
}
const tmp = `${file}.tmp-${process.pid}`
fs.writeFileSync(tmp, src.split(BUGGY).join(FIXED))
fs.renameSync(tmp, file)
console.log(`patch-flying-squid: applied (${n} call sites)`)
