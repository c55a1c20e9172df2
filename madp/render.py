"""RGB frames of a coverage world, vectorised numpy: importance map, Voronoi cells, trails, robots, text.

One renderer for everything that draws the world as pixels: the environments' ``render()``
(:mod:`madp.envs`) and the MP4 videos of ``madp rollout --video`` and ``madp eval --video``
(:mod:`madp.video`), so a video's frame t is exactly what ``render()`` returns at step t.

A frame is ``size × size`` pixels, north up (image row 0 is the world's top edge, y = W); each pixel
shows the world at its centre. Maps in madp are indexed ``[x, y]``, so the map is transposed and
flipped to image order. Layers, bottom to top:

- the importance map, white (0) to orange-red (the map's peak), block-averaged to the frame;
- the Voronoi cells of the robots (nearest robot per pixel centre), their edges in dark blue;
- each robot's trail, its positions from step 0 to now, in the robot's colour (:func:`robot_colors`,
  the colours of the Foxglove recordings);
- the robots, black discs;
- a line of text at the top left: the step ``t`` and J(t)/J(0), in a 5 × 7 bitmap font.

No Python loop runs over pixels: the Voronoi pass loops over robots (one vectorised pass over the
frame each), the trails and the text are array indexing.
"""

from __future__ import annotations

import numpy as np

BACKGROUND = np.array([255, 255, 255], dtype=np.float32)
IMPORTANCE = np.array([200, 60, 20], dtype=np.float32)  # colour of importance 1
CELL_EDGE = np.array([40, 40, 160], dtype=np.uint8)
ROBOT = np.array([0, 0, 0], dtype=np.uint8)
TEXT = np.array([0, 0, 0], dtype=np.uint8)
#: How far the box behind the text is blended towards white (0: not at all, 1: opaque white).
TEXT_BOX_ALPHA = 0.8
#: Trail colours are the robots' colours darkened by this factor, so light hues show on white.
TRAIL_SHADE = 0.8

_GOLDEN = 0.6180339887498949


def robot_colors(n: int) -> np.ndarray:
    """Stable, distinct RGB colours ``[n, 3]`` in [0, 1]: robot ``i`` gets hue ``i · 0.618… mod 1``.

    The colour of robot ``i`` does not depend on ``n``; neighbouring indices land far apart on the hue
    wheel, and value alternates between two levels every other robot for more contrast.
    """
    i = np.arange(n)
    h = (i * _GOLDEN) % 1.0
    s = np.full(n, 0.8)
    v = np.where(i % 2 == 0, 1.0, 0.8)
    h6 = h * 6.0
    sector = np.floor(h6).astype(int) % 6
    f = h6 - np.floor(h6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    table = np.stack([
        np.stack([v, t, p], 1), np.stack([q, v, p], 1), np.stack([p, v, t], 1),
        np.stack([p, q, v], 1), np.stack([t, p, v], 1), np.stack([v, p, q], 1),
    ])  # [6, n, 3]
    return table[sector, i]


# --- text: a 5 x 7 bitmap font of the characters the frames use ----------------------------------
_FONT_ROWS = {
    "0": (" ### ", "#   #", "#  ##", "# # #", "##  #", "#   #", " ### "),
    "1": ("  #  ", " ##  ", "  #  ", "  #  ", "  #  ", "  #  ", " ### "),
    "2": (" ### ", "#   #", "    #", "   # ", "  #  ", " #   ", "#####"),
    "3": ("#####", "   # ", "  #  ", "   # ", "    #", "#   #", " ### "),
    "4": ("   # ", "  ## ", " # # ", "#  # ", "#####", "   # ", "   # "),
    "5": ("#####", "#    ", "#### ", "    #", "    #", "#   #", " ### "),
    "6": ("  ## ", " #   ", "#    ", "#### ", "#   #", "#   #", " ### "),
    "7": ("#####", "    #", "   # ", "  #  ", " #   ", " #   ", " #   "),
    "8": (" ### ", "#   #", "#   #", " ### ", "#   #", "#   #", " ### "),
    "9": (" ### ", "#   #", "#   #", " ####", "    #", "   # ", " ##  "),
    ".": ("     ", "     ", "     ", "     ", "     ", " ##  ", " ##  "),
    "=": ("     ", "     ", "#####", "     ", "#####", "     ", "     "),
    "(": ("   # ", "  #  ", " #   ", " #   ", " #   ", "  #  ", "   # "),
    ")": (" #   ", "  #  ", "   # ", "   # ", "   # ", "  #  ", " #   "),
    "/": ("     ", "    #", "   # ", "  #  ", " #   ", "#    ", "     "),
    "-": ("     ", "     ", "     ", "#####", "     ", "     ", "     "),
    "J": ("  ###", "   # ", "   # ", "   # ", "   # ", "#  # ", " ##  "),
    "t": (" #   ", " #   ", "#### ", " #   ", " #   ", " #  #", "  ## "),
    " ": ("     ",) * 7,
}
_FONT_CHARS = "".join(_FONT_ROWS)
#: [characters, 7, 6] glyph masks, one blank column of spacing on the right of each.
_GLYPHS = np.pad(np.array([[[c == "#" for c in row] for row in _FONT_ROWS[ch]] for ch in _FONT_CHARS]),
                 ((0, 0), (0, 0), (0, 1)))


def text_mask(text: str, scale: int = 1) -> np.ndarray:
    """[7·scale, 6·scale·len(text)] bool: ``text`` in the 5 × 7 font (characters it lacks are blank)."""
    idx = np.array([_FONT_CHARS.find(c) if c in _FONT_ROWS else _FONT_CHARS.index(" ") for c in text], dtype=np.int64)
    line = _GLYPHS[idx].transpose(1, 0, 2).reshape(7, -1)  # glyphs side by side
    return np.repeat(np.repeat(line, scale, axis=0), scale, axis=1)


def status_line(step: int | None, cost: float | None) -> str:
    """The frame's text: ``t=<step>  J(t)/J(0)=<cost>`` (the parts given)."""
    parts = []
    if step is not None:
        parts.append(f"t={int(step)}")
    if cost is not None:
        parts.append(f"J(t)/J(0)={float(cost):.3f}")
    return "  ".join(parts)


def draw_text(img: np.ndarray, text: str, scale: int) -> None:
    """Write ``text`` at the top left of ``img`` (in place) over a box blended towards white."""
    if not text:
        return
    mask = text_mask(text, scale)
    pad = 2 * scale
    h, w = min(mask.shape[0], img.shape[0] - 2 * pad), min(mask.shape[1], img.shape[1] - 2 * pad)
    if h <= 0 or w <= 0:
        return
    box = img[: h + 2 * pad, : w + 2 * pad]
    box[:] = (box * (1.0 - TEXT_BOX_ALPHA) + BACKGROUND * TEXT_BOX_ALPHA).astype(np.uint8)
    box[pad: pad + h, pad: pad + w][mask[:h, :w]] = TEXT


# --- the map and the robots ----------------------------------------------------------------------
def _downsample(world_map: np.ndarray, size: int) -> np.ndarray:
    """Block means of the [W, W] map to [size, size] (nearest sampling when W is not a multiple)."""
    w = world_map.shape[0]
    if w % size == 0:
        k = w // size
        return world_map.reshape(size, k, size, k).mean(axis=(1, 3))
    idx = ((np.arange(size) + 0.5) * w / size).astype(np.int64)
    return world_map[np.ix_(idx, idx)]


def map_image(world_map: np.ndarray, size: int) -> np.ndarray:
    """[size, size, 3] uint8: the importance map shaded from white, north up."""
    phi = _downsample(world_map, size)  # [x, y]
    peak = float(phi.max()) or 1.0
    shade = (phi / peak).T[::-1]  # image [row, col] = [top-down y, x]
    return (BACKGROUND + shade[..., None] * (IMPORTANCE - BACKGROUND)).astype(np.uint8)


class FrameRenderer:
    """Frames of one world map at ``size`` pixels; the shaded map is computed once.

    ``robot_radius_px`` defaults to size / 128 (4 px at 512) but at least 2 px; trails are
    ``max(1, size // 256)`` pixels wide and the text is scaled by the same factor.
    """

    def __init__(self, world_map: np.ndarray, size: int = 512, robot_radius_px: float | None = None):
        if int(size) < 1:
            raise ValueError(f"frame size must be >= 1 pixel, got {size}")
        self.size = int(size)
        self.world_m = float(world_map.shape[0])
        self.background = map_image(world_map, self.size)
        self.robot_radius_px = float(robot_radius_px) if robot_radius_px is not None else max(2.0, self.size / 128)
        self.scale = max(1, self.size // 256)
        centres = (np.arange(self.size, dtype=np.float32) + 0.5) * (self.world_m / self.size)
        self._xs, self._ys = centres[None, :], centres[::-1, None]  # [1, size] columns, [size, 1] rows (y up)

    def pixels(self, xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Image (row, column) of the pixels holding world points ``xy_m [..., 2]``, clipped to the frame."""
        f = self.size / self.world_m
        col = np.clip(np.floor(xy_m[..., 0] * f), 0, self.size - 1).astype(np.int64)
        row = np.clip(self.size - 1 - np.floor(xy_m[..., 1] * f), 0, self.size - 1).astype(np.int64)
        return row, col

    def _trails(self, img: np.ndarray, trail_m: np.ndarray) -> None:
        """Polylines through ``trail_m [T+1, N, 2]`` (each robot's positions), sampled at least once
        per pixel along every segment."""
        p = np.asarray(trail_m, dtype=np.float64)
        colors = (robot_colors(p.shape[1]) * 255 * TRAIL_SHADE).astype(np.uint8)
        if len(p) > 1:
            seg = p[1:] - p[:-1]  # [T, N, 2]
            m = int(np.ceil(np.abs(seg).max() * self.size / self.world_m)) + 1
            frac = np.arange(m, dtype=np.float64) / m
            pts = p[:-1, :, None, :] + frac[None, None, :, None] * seg[:, :, None, :]  # [T, N, m, 2]
            pts = np.concatenate([pts.transpose(1, 0, 2, 3).reshape(p.shape[1], -1, 2), p[-1][:, None]], axis=1)
        else:
            pts = p.transpose(1, 0, 2)  # [N, 1, 2]
        row, col = self.pixels(pts)  # [N, P]
        rgb = np.broadcast_to(colors[:, None, :], (*row.shape, 3))
        for dr in range(self.scale):  # trail width, a few pixels
            for dc in range(self.scale):
                img[np.minimum(row + dr, self.size - 1), np.minimum(col + dc, self.size - 1)] = rgb

    def __call__(self, positions_m: np.ndarray, trail_m: np.ndarray | None = None, step: int | None = None,
                 cost: float | None = None) -> np.ndarray:
        """[size, size, 3] uint8 frame of the robots at ``positions_m [N, 2]``; ``trail_m [T+1, N, 2]``
        (positions from step 0 to now) adds the trails, ``step`` and ``cost`` (J(t)/J(0)) the text."""
        img = self.background.copy()
        p = np.asarray(positions_m, dtype=np.float32)
        best = np.full((self.size, self.size), np.inf, dtype=np.float32)
        label = np.zeros((self.size, self.size), dtype=np.int32)
        for i, (px, py) in enumerate(p):  # N passes over the frame, each vectorised
            d2 = (self._xs - px) ** 2 + (self._ys - py) ** 2
            closer = d2 < best
            best = np.where(closer, d2, best)
            label = np.where(closer, i, label)
        edge = np.zeros((self.size, self.size), dtype=bool)
        edge[:, 1:] |= label[:, 1:] != label[:, :-1]
        edge[1:, :] |= label[1:, :] != label[:-1, :]
        img[edge] = CELL_EDGE
        if trail_m is not None and len(trail_m):
            self._trails(img, trail_m)
        img[np.sqrt(best) * (self.size / self.world_m) <= self.robot_radius_px] = ROBOT
        draw_text(img, status_line(step, cost), self.scale)
        return img


def render_frame(world_map: np.ndarray, positions_m: np.ndarray, size: int = 512, robot_radius_px: float | None = None,
                 *, trail_m: np.ndarray | None = None, step: int | None = None, cost: float | None = None) -> np.ndarray:
    """One frame (see :class:`FrameRenderer`); for many frames of one map, keep a FrameRenderer."""
    return FrameRenderer(world_map, size, robot_radius_px)(positions_m, trail_m, step, cost)
