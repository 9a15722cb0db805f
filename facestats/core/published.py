"""Published figures of the source papers, in one place.

Every number here is quoted from a seed paper; code that reproduces or is tested
against a published figure imports it from this module.

Weyrich et al. 2006 = *Analysis of Human Faces using a Measurement-Based Skin
Reflectance Model*, SIGGRAPH 2006.  Jensen et al. 2001 = *A Practical Model for
Subsurface Light Transport*, SIGGRAPH 2001 (parameters quoted in Suzuki,
Mukaigawa & Yagi, Fig. 3).  Suzuki, Mukaigawa & Yagi = *Fitting of Subsurface
Scattering Model to Translucent Object* (Osaka University; in Japanese).
"""

from __future__ import annotations

import numpy as np

#: Relative index of refraction of skin (Weyrich §3, after Tuchin 2000).
ETA_SKIN = 1.38

#: Weyrich Table 1: mean and "Var." of σtr (mm⁻¹) per site, channel R, G, B.
TABLE1_MEAN = {
    "cheek": np.array([0.5572, 0.9751, 1.5494]),
    "forehead": np.array([0.5443, 0.9831, 1.5499]),
    "neck": np.array([0.6911, 1.2488, 1.9159]),
}
TABLE1_VAR = {
    "cheek": np.array([0.1727, 0.2089, 0.1881]),
    "forehead": np.array([0.0756, 0.1696, 0.2607]),
    "neck": np.array([0.2351, 0.3686, 0.4230]),
}

#: Weyrich §5.4: mean σtr over all subjects, cheek and forehead, neck excluded (mm⁻¹).
SIGMA_TR_AVG = np.array([0.5508, 0.9791, 1.5497])

#: Weyrich §5.4 / Fig. 11: ℓd (mm, R G B) of the least and the most translucent subject.
ELL_D_MIN = np.array([1.0904, 0.6376, 0.6035])
ELL_D_MAX = np.array([2.8106, 1.2607, 0.6590])

#: Weyrich Table 2: subjects (male, female) per Fitzpatrick skin type (I and II grouped as 2).
TABLE2_COUNTS = {2: (8, 6), 3: (49, 18), 4: (40, 8), 5: (13, 2), 6: (4, 1)}

#: Weyrich §7: subjects (male, female) per age group.
AGE_COUNTS = {"20s": (61, 18), "30s": (37, 10), "40s": (10, 2), "50s+": (6, 5)}

#: Weyrich §7: number of subjects (114 male / 35 female).
N_SUBJECTS = 149

#: Weyrich §7 / Fig. 16: CCA of the Torrance-Sparrow parameters.
CCA_PRINCIPAL = (0.768, 0.585)
CCA_DIRECT = {"skin_type": 0.766, "gender": 0.573, "age": 0.537}

#: Weyrich §7 / Fig. 15: regions with the highest ρs, the largest variance, the smallest m.
HIGHEST_RHO_S = (6, 3, 4, 8, 2)
LARGEST_VARIANCE = (8, 1, 3, 9, 10)
SMALLEST_M = 6

#: Jensen et al. 2001 (Suzuki Fig. 3): (σ's, σa) in mm⁻¹ of the red channel, η = 1.3,
#: with the total diffuse reflectance R_d tabulated by Jensen et al.
JENSEN_SKIN1 = {"sigma_s_prime": 0.74, "sigma_a": 0.032, "eta": 1.3, "Rd": 0.44}
JENSEN_APPLE = {"sigma_s_prime": 2.29, "sigma_a": 0.0030, "eta": 1.3, "Rd": 0.85}

#: Weyrich §5: the dome and the contact sensor.
N_CAMERAS = 16
N_LEDS = 150
N_FIBERS = 28
SENSOR_BRACKET_IMAGES = 23
SENSOR_BRACKET_STOP = 2.0 / 3.0
LUMITEXEL_SAMPLES_TYPICAL = 900
LUMITEXEL_SAMPLES_MAX = 1200
GRAZING_LIMIT_DEG = 80.0

#: Suzuki, Mukaigawa & Yagi Table 1: the simulated object (σs is the reduced σ's, g = 0; mm⁻¹).
SUZUKI_TABLE1 = {"sigma_s_prime": 2.19, "sigma_a": 0.0021, "eta": 1.3}
#: Suzuki et al. Table 3: (σ's, σa) estimated per quantisation width (mm) in their simulation.
SUZUKI_TABLE3 = {
    8.0: (0.28, 0.0001),
    4.0: (0.55, 0.0001),
    2.0: (1.49, 0.0028),
    1.0: (0.49, 0.0030),
    0.5: (2.63, 0.0001),
    0.25: (2.19, 0.0021),
    0.125: (2.09, 0.0025),
    0.0625: (2.05, 0.0030),
    0.03125: (0.36, 0.0001),
}
#: Suzuki et al. Table 4: (σ's, σa) in mm⁻¹ of real cubes (η = 1.3).
SUZUKI_TABLE4 = {"PP": (0.14, 0.0030), "PE": (0.34, 0.0001), "POM": (0.46, 0.0001)}
