"""Search the covariate effect strengths of the synthetic population against Weyrich Fig. 16.

Prints, for a grid of (skin type, gender, age) strengths, the canonical correlations
of the 149 × 20 region means of the truth against (skin type, gender, age), averaged
over seeds, sorted by distance to the published figures.  The population is drawn as the
embedded default's (its face at its map size: the region means' sampling noise depends
on how many texels each region has).  ``facestats.acquire.synthetic.population`` records
the chosen values.

    python scripts/calibrate_population.py [SEEDS]
"""

import itertools
import sys

import numpy as np

from facestats.acquire.synthetic import population as pop
from facestats.analysis.cca import cca
from facestats.core.conventions import DEFAULT_MAP_SIZE
from facestats.core.published import CCA_DIRECT, CCA_PRINCIPAL

TARGET = np.array([*CCA_PRINCIPAL, CCA_DIRECT["skin_type"], CCA_DIRECT["gender"], CCA_DIRECT["age"]])
GRID = ([0.0145, 0.016, 0.0175, 0.019], [0.010, 0.011, 0.012], [0.007, 0.008])


def statistics(population):
    subjects = [s for s in population.subjects if s.condition == "normal"]
    x = np.array(
        [
            [v for r in range(1, 11) for v in (s.ts_rho_s[s.region_map == r].mean(), s.ts_m[s.region_map == r].mean())]
            for s in subjects
        ]
    )
    y = np.array([[max(s.skin_type, 2), s.gender == "F", s.age] for s in subjects], float)
    return np.r_[cca(x, y).correlations[:2], [cca(x, y[:, [j]]).correlations[0] for j in range(3)]]


def main(seeds=8):
    rows = []
    for ks, kg, ka in itertools.product(*GRID):
        pop.EFFECT_STRENGTH.update(skin_type=ks, gender=kg, age=ka)
        vals = np.mean(
            [
                statistics(pop.synthesize_population(seed=s, map_size=DEFAULT_MAP_SIZE, conditions=False))
                for s in range(seeds)
            ],
            0,
        )
        rows.append((float(np.sqrt(np.mean((vals - TARGET) ** 2))), ks, kg, ka, vals.round(3)))
        print(*rows[-1], flush=True)
    print("best:")
    for row in sorted(rows, key=lambda r: r[0])[:8]:
        print(row)


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:]))
