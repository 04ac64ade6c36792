"""The colonnade: four turned columns with painted rings on a stepped base, carrying a beam with a triglyph frieze."""

from __future__ import annotations

import numpy as np

from ..data.mesh import TexturedMesh
from .geometry import box, revolve
from .texture import AtlasBuilder, Noise, palette

PAINTS = [[0.70, 0.22, 0.16], [0.16, 0.28, 0.58], [0.82, 0.62, 0.18], [0.20, 0.46, 0.32], [0.55, 0.20, 0.40]]
STONE = np.float32([0.86, 0.80, 0.68])
MARBLE = np.float32([0.93, 0.91, 0.86])
HIDDEN = ("step0:-z", "step1:-z", "beam:+z", "plinth:-z", "abacus:+z")  # charts nobody sees: few texels


def build_colonnade(rng: np.random.Generator) -> TexturedMesh:
    """Four columns on a two-step base carrying a beam; each column has its own rings and colours."""
    return _Colonnade(rng).build()


class _Colonnade:
    """One colonnade: its measures, the random choices of each column, and the paint of every chart."""

    n_col, spacing = 4, 1.2
    step_h, plinth_h, abacus_h, beam_h, cornice_h = 0.25, 0.12, 0.14, 0.45, 0.14
    shaft_h = 2.2

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.noise = Noise(rng)
        self.half = self.n_col * self.spacing / 2 + 0.3
        self.z_base = 2 * self.step_h
        self.z_beam = self.z_base + self.plinth_h + self.shaft_h + self.abacus_h
        self.z_cornice = self.z_beam + self.beam_h
        self.columns: list[dict] = []  # each column's rings, colours, flare and flutes

    def build(self) -> TexturedMesh:
        half, z_base, z_beam, z_cornice = self.half, self.z_base, self.z_beam, self.z_cornice
        atlas = AtlasBuilder()
        atlas.add_box_projected("step0", *box((-half, -0.8, 0), (half, 0.8, self.step_h)))
        atlas.add_box_projected("step1", *box((-half + 0.15, -0.65, self.step_h), (half - 0.15, 0.65, z_base)))
        for i in range(self.n_col):
            self.add_column(atlas, i)
        atlas.add_box_projected("beam", *box((-half + 0.15, -0.45, z_beam), (half - 0.15, 0.45, z_beam + self.beam_h)))
        atlas.add_box_projected(
            "cornice", *box((-half + 0.05, -0.55, z_cornice), (half - 0.05, 0.55, z_cornice + self.cornice_h))
        )
        self.triglyph = self.rng.uniform(0.25, 0.55, 3) * np.float32([0.4, 0.6, 1.0])  # frieze colours
        self.metope = palette(self.rng, PAINTS, 1)[0]
        return atlas.build("colonnade", self.paint, size=(1024, 1024), detail=self.detail)

    def add_column(self, atlas: AtlasBuilder, i: int) -> None:
        """Column ``i``: its random rings and colours, a square plinth, the turned shaft, a square abacus."""
        rng, shaft_h = self.rng, self.shaft_h
        cx = (i - (self.n_col - 1) / 2) * self.spacing
        z0 = self.z_base + self.plinth_h
        rings = np.sort(rng.choice(np.arange(0.2, 0.8, 0.12), rng.integers(1, 4), replace=False)) * shaft_h
        spec = dict(
            rings=rings,
            ring_colors=palette(rng, PAINTS, len(rings)),
            flare=rng.uniform(0.30, 0.36),
            flutes=int(rng.choice([12, 16, 20])),
            band=palette(rng, PAINTS, 2),
            z0=z0,
        )
        self.columns.append(spec)
        t, r = self.profile(spec)
        atlas.add_box_projected(f"col{i}.plinth", *box((cx - 0.32, -0.32, self.z_base), (cx + 0.32, 0.32, z0)))
        atlas.add_charted(f"col{i}.shaft", *revolve(r, z0 + t, (cx, 0.0), 32, 0.24))
        z1 = z0 + shaft_h
        atlas.add_box_projected(f"col{i}.abacus", *box((cx - 0.38, -0.38, z1), (cx + 0.38, 0.38, z1 + self.abacus_h)))

    def profile(self, spec: dict):
        """The shaft's profile ``(t, r(t))``: torus base, tapering shaft with raised rings, neck, flared capital."""
        shaft_h = self.shaft_h
        t = np.linspace(0, shaft_h, int(shaft_h / 0.025) + 1)
        r = 0.24 - 0.035 * (t / shaft_h) ** 2
        r = r + 0.06 * np.sqrt(np.clip(1 - ((t - 0.07) / 0.07) ** 2, 0, 1))  # base torus
        for zr in spec["rings"]:
            r = r + 0.06 * np.sin(np.pi * np.clip((t - zr) / 0.16, 0, 1))
        ech = np.clip((t - (shaft_h - 0.2)) / 0.2, 0, 1)  # the echinus
        r = r + (spec["flare"] - 0.205) * np.sin(ech * np.pi / 2) ** 1.5
        return t, r

    # ------------------------------------------------------------------ paint
    def stone_blocks(self, p, q, w, h, base=STONE, offset=0.0):
        """Ashlar: blocks of ``w × h`` with thin dark joints and a grainy surface."""
        row = np.floor(q / h)
        pp = p + offset * (row % 2)
        u, v = pp - np.floor(pp / w) * w, q - row * h
        col = base * (0.85 + 0.25 * self.noise.fbm(p * 8 + row, q * 8, octaves=3))[..., None]
        joint = np.minimum(np.minimum(u, w - u), np.minimum(v, h - v)) < 0.012
        return np.where(joint[..., None], base * 0.55, col)

    def shaft(self, spec, p, q):
        """A column's shaft: veined marble with painted flutes, chevron rings, a coloured base and egg-and-dart capital."""
        noise, shaft_h = self.noise, self.shaft_h
        theta, z = p / 0.24, q - spec["z0"]
        veins = np.abs(np.sin(6 * noise.fbm(p * 2.5, q * 1.2) * np.pi + p * 3)) < 0.06
        col = MARBLE * (0.9 + 0.12 * np.cos(spec["flutes"] * theta))[..., None]  # painted flutes
        col[veins] *= np.float32([0.72, 0.72, 0.76])
        for zr, rc in zip(spec["rings"], spec["ring_colors"]):
            inside = (z > zr) & (z < zr + 0.16)
            chevron = ((theta * 8 / np.pi + 10 * np.abs(z - zr - 0.08)) % 2) < 1
            col[inside] = np.where(chevron[inside][:, None], rc, rc * 0.55 + 0.4)
        base = z < 0.14
        cap = z > shaft_h - 0.2
        eggs = np.cos(12 * theta) * np.sin(np.pi * np.clip((z - shaft_h + 0.2) / 0.2, 0, 1)) > 0.35
        col[base] = spec["band"][0] * (0.8 + 0.3 * noise(p[base] * 30, q[base] * 30))[:, None]
        col[cap] = np.where(eggs[cap][:, None], spec["band"][1], np.float32([0.85, 0.68, 0.25]))
        neck = (z > shaft_h - 0.26) & (z <= shaft_h - 0.2)
        col[neck] = spec["band"][1] * 0.8
        return col

    def frieze(self, p, q):
        """Front and back of the beam: plain architrave below, triglyphs and painted metopes above."""
        beam_h, spacing, triglyph = self.beam_h, self.spacing, self.triglyph
        z = q - self.z_beam
        col = self.stone_blocks(p, q, 1.2, beam_h * 0.45)
        upper = z > beam_h * 0.45
        u = (p + spacing / 4) % (spacing / 2) / (spacing / 2)  # two panels per column spacing
        is_tri = (u < 0.4) & upper
        grooves = ((u * 10).astype(int) % 3 == 1) & is_tri
        col[is_tri] = triglyph
        col[grooves] = triglyph * 0.5
        is_met = upper & ~is_tri
        disc = ((u - 0.7) * spacing / 2) ** 2 + (z - beam_h * 0.72) ** 2 < 0.07**2
        col[is_met] = self.metope * (0.85 + 0.2 * self.noise(p[is_met] * 20, q[is_met] * 20))[:, None]
        col[is_met & disc] = np.float32([0.95, 0.92, 0.8])
        col[np.abs(z - beam_h * 0.45) < 0.015] = STONE * 0.5
        return col

    def plinth_or_abacus(self, spec, part, direction, p, q):
        """Dark stone, the sides with a painted band: a wave line on the plinth, gold dots on the abacus."""
        col = self.stone_blocks(p, q, 2.0, 2.0, base=np.float32([0.55, 0.5, 0.45]))
        if direction[1] in "xy":
            if part.endswith("plinth"):  # a wave line on a coloured band
                mid = self.z_base + self.plinth_h / 2
                col[np.abs(q - mid) < 0.035] = spec["band"][0]
                col[np.abs(q - mid - 0.02 * np.sin(p * 40)) < 0.007] = np.float32([0.95, 0.92, 0.85])
            else:  # abacus: gold dots on a coloured band
                mid = spec["z0"] + self.shaft_h + self.abacus_h / 2
                col[np.abs(q - mid) < 0.045] = spec["band"][1]
                dot = ((p % 0.1) - 0.05) ** 2 + (q - mid) ** 2 < 0.022**2
                col[dot] = np.float32([0.9, 0.72, 0.25])
        return col

    def paint(self, chart, p, q):
        part, direction = chart.split(":") if ":" in chart else (chart, "")
        if part.startswith("col"):  # col<i>.shaft, .plinth or .abacus
            spec = self.columns[int(part[3:].split(".")[0])]
            if part.endswith(".shaft"):
                return self.shaft(spec, p, q)
            return self.plinth_or_abacus(spec, part, direction, p, q)
        if part == "beam" and direction in ("+y", "-y", "+x", "-x"):
            return self.frieze(p, q)
        if part == "cornice" and direction in ("+y", "-y", "+x", "-x"):
            dentil = ((p * 10) % 1 < 0.5) & ((q - self.z_cornice) < self.cornice_h * 0.5)
            col = self.stone_blocks(p, q, 3.0, 3.0)
            col[dentil] *= 0.6
            return col
        if direction == "+z":  # floor tiles of the steps, roof slabs
            return self.stone_blocks(p, q, 0.4, 0.4, offset=0.2)
        return self.stone_blocks(p, q, 0.8, self.step_h, offset=0.4)  # sides of the steps, undersides

    @staticmethod
    def detail(chart):
        return 0.1 if chart.endswith(HIDDEN) else 1.6 if chart.endswith("shaft") else 1.0
