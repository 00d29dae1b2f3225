"""An RGB picture of an Overcooked state (numpy and PIL, not jitted), drawn from its init vector (:mod:`.kitchen`).

Cells: floor (sand), counters (brown), pots (dark, with a dot per onion and a bar of the cooking: red while it
cooks, green when the soup is ready), onion piles (yellow onions), plate piles (stacked plates), serving spots
(green). Items on counters and in hands: an onion (yellow), a plate (white), a soup (a plate with orange soup).
The human is orange, the robot blue; a dark wedge points where each faces and what it holds sits on that side.
"""
from __future__ import annotations

import numpy as np

from . import kitchen as kt

FLOOR_RGB = (236, 226, 204)
COUNTER_RGB = (158, 124, 92)
POT_RGB = (58, 58, 64)
GOAL_RGB = (96, 176, 96)
ONION_RGB = (232, 200, 58)
PLATE_RGB = (250, 250, 250)
SOUP_RGB = (226, 120, 40)
AGENT_RGB = ((240, 120, 40), (40, 160, 230))  # human, robot
DIRS = np.array([(0, -1), (0, 1), (1, 0), (-1, 0)], np.float32)  # facing id -> (dx, dy), y down


def render_frame(k: kt.Kitchen, init: np.ndarray, width: int = 320, height: int = 240) -> np.ndarray:
    """An RGB frame (height, width, 3) uint8 of the game state ``init`` encodes, the kitchen centred in it."""
    from PIL import Image, ImageDraw

    sl = k.init_slices()
    v = np.rint(np.asarray(init, np.float32)).astype(np.int64)
    cell = max(1.0, min(width / k.width, height / k.height))
    x0, y0 = (width - cell * k.width) / 2, (height - cell * k.height) / 2
    img = Image.new("RGB", (int(width), int(height)), (40, 40, 40))
    d = ImageDraw.Draw(img)

    def box(x, y, inset=0.0):
        return [x0 + (x + inset) * cell, y0 + (y + inset) * cell, x0 + (x + 1 - inset) * cell - 1,
                y0 + (y + 1 - inset) * cell - 1]

    def disc(cx, cy, r, fill, outline=None):
        px, py = x0 + cx * cell, y0 + cy * cell
        d.ellipse([px - r * cell, py - r * cell, px + r * cell, py + r * cell], fill=fill, outline=outline,
                  width=max(1, int(cell / 24)))

    def item(code, cx, cy, r):
        if code == 1:
            disc(cx, cy, r, ONION_RGB, (120, 90, 20))
        elif code in (2, 3):
            disc(cx, cy, r, PLATE_RGB, (120, 120, 120))
            if code == 3:
                disc(cx, cy, r * 0.6, SOUP_RGB)

    colours = {kt.FLOOR: FLOOR_RGB, kt.GOAL_CELL: GOAL_RGB}
    for y in range(k.height):
        for x in range(k.width):
            kind = int(k.cells[y, x])
            d.rectangle(box(x, y), fill=colours.get(kind, COUNTER_RGB))
            if kind == kt.GOAL_CELL:
                d.rectangle(box(x, y, 0.2), outline=(230, 250, 230), width=max(1, int(cell / 16)))
            elif kind == kt.ONION_CELL:
                for dx, dy in ((0.35, 0.4), (0.65, 0.4), (0.5, 0.65)):
                    disc(x + dx, y + dy, 0.16, ONION_RGB, (120, 90, 20))
            elif kind == kt.PLATE_CELL:
                for j in range(3):
                    disc(x + 0.5, y + 0.62 - 0.1 * j, 0.28, PLATE_RGB, (120, 120, 120))
    for j, (x, y) in enumerate(k.pots):
        d.rectangle(box(x, y, 0.1), fill=POT_RGB)
        onions, timer = v[sl["pot_onions"]][j], v[sl["pot_timer"]][j]
        for i in range(int(onions)):
            disc(x + 0.3 + 0.2 * i, y + 0.4, 0.09, ONION_RGB)
        if onions >= kt.MAX_ONIONS:
            done = (kt.COOK_STEPS - timer) / kt.COOK_STEPS
            bar = box(x, y, 0.18)
            bar[1] = y0 + (y + 0.68) * cell
            bar[3] = y0 + (y + 0.8) * cell
            d.rectangle(bar, outline=(200, 200, 200))
            bar[2] = bar[0] + (bar[2] - bar[0]) * done
            d.rectangle(bar, fill=(80, 200, 80) if timer == 0 else (220, 60, 40))
    for j, (x, y) in enumerate(k.counters):
        item(v[sl["counters"]][j], x + 0.5, y + 0.5, 0.22)
    pos = v[sl["pos"]].reshape(2, 2)
    for a in range(2):
        cx, cy = pos[a, 0] + 0.5, pos[a, 1] + 0.5
        f = DIRS[int(np.clip(v[sl["dir"]][a], 0, 3))]
        disc(cx, cy, 0.34, AGENT_RGB[a], (30, 30, 30))
        side = np.array([-f[1], f[0]])
        tip, base = np.array([cx, cy]) + 0.34 * f, np.array([cx, cy]) + 0.12 * f
        wedge = [tip, base + 0.14 * side, base - 0.14 * side]
        d.polygon([(x0 + p[0] * cell, y0 + p[1] * cell) for p in wedge], fill=(30, 30, 30))
        item(v[sl["held"]][a], cx + 0.3 * f[0], cy + 0.3 * f[1], 0.15)
    return np.asarray(img, np.uint8)
