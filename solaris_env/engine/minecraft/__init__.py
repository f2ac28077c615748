"""The optional real-Minecraft backend of the engine (Minecraft 1.20.1, no Mojang client, no GPU).

A flying-squid server (``server.js``) on 127.0.0.1 and two mineflayer bots (``record.js``) whose
first-person views are rendered in the same Node process by prismarine-viewer on headless-gl (Mesa
llvmpipe on Xvfb), one frame per bot per 20 Hz physics tick together with that tick's action data.
Python installs it and tells whether it is ready (:mod:`.install`: ``solaris-engine setup-minecraft``,
``setup_problem``), supervises the processes (:mod:`.supervisor`), turns the raw tick rows into Mineflayer
action records and the ground-truth sidecar (:mod:`.records`) and writes the voxel engine's Duet/eval layout
(:mod:`.collect`).

The Node sources and the committed ``package.json`` / ``package-lock.json`` live in this directory;
``node_modules`` (~1 GB, built by ``setup-minecraft``) is git-ignored. Mojang's textures come inside
the prismarine-viewer npm package.
"""

from __future__ import annotations

from pathlib import Path

NODE_DIR = Path(__file__).resolve().parent
MINECRAFT_VERSION = "1.20.1"
