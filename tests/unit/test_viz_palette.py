"""The viewer's colours: nothing drawn may be taken for a force arrow. Every colour of the palette
but the three arrows' is at least ARROW_CONTRAST (CIEDE2000, the CIE's colour difference) from
each arrow's; the difference is checked against Sharma, Wu and Dalal's published test pairs."""

import numpy as np
import pytest

from teleop.viz.shapes import ARROW_CONTRAST, ARROW_KEYS, COLORS


def lab(color: int) -> np.ndarray:
    """CIE L*a*b* (D65) of an sRGB colour 0xRRGGBB."""
    rgb = np.array([(color >> 16) & 255, (color >> 8) & 255, color & 255]) / 255.0
    lin = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    M = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    xyz = M @ lin / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def ciede2000(lab1, lab2) -> float:
    """The CIEDE2000 colour difference of two L*a*b* colours (Sharma, Wu, Dalal 2005, eqs. 1-17)."""
    L1, a1, b1 = lab1
    L2, a2, b2 = lab2
    Cb = 0.5 * (np.hypot(a1, b1) + np.hypot(a2, b2))
    G = 0.5 * (1 - np.sqrt(Cb**7 / (Cb**7 + 25.0**7)))
    a1p, a2p = (1 + G) * a1, (1 + G) * a2
    C1, C2 = np.hypot(a1p, b1), np.hypot(a2p, b2)
    h1 = np.degrees(np.arctan2(b1, a1p)) % 360 if C1 else 0.0
    h2 = np.degrees(np.arctan2(b2, a2p)) % 360 if C2 else 0.0
    dh = 0.0 if C1 * C2 == 0 else (h2 - h1 + 180) % 360 - 180
    dL, dC, dH = L2 - L1, C2 - C1, 2 * np.sqrt(C1 * C2) * np.sin(np.radians(dh / 2))
    Lb, Cbp = 0.5 * (L1 + L2), 0.5 * (C1 + C2)
    if C1 * C2 == 0:
        hb = h1 + h2
    elif abs(h1 - h2) <= 180:
        hb = 0.5 * (h1 + h2)
    else:
        hb = 0.5 * (h1 + h2 + (360 if h1 + h2 < 360 else -360))
    T = (1 - 0.17 * np.cos(np.radians(hb - 30)) + 0.24 * np.cos(np.radians(2 * hb))
         + 0.32 * np.cos(np.radians(3 * hb + 6)) - 0.20 * np.cos(np.radians(4 * hb - 63)))
    SL = 1 + 0.015 * (Lb - 50) ** 2 / np.sqrt(20 + (Lb - 50) ** 2)
    SC, SH = 1 + 0.045 * Cbp, 1 + 0.015 * Cbp * T
    RT = -2 * np.sqrt(Cbp**7 / (Cbp**7 + 25.0**7)) * np.sin(np.radians(60 * np.exp(-(((hb - 275) / 25) ** 2))))
    return float(np.sqrt((dL / SL) ** 2 + (dC / SC) ** 2 + (dH / SH) ** 2 + RT * (dC / SC) * (dH / SH)))


@pytest.mark.parametrize("lab1, lab2, expected", [  # Sharma, Wu, Dalal's test data, pairs 1, 7, 17, 25
    ((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
    ((50.0, 0.0, 0.0), (50.0, -1.0, 2.0), 2.3669),
    ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
    ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644),
])
def test_ciede2000_meets_the_published_test_pairs(lab1, lab2, expected):
    assert ciede2000(lab1, lab2) == pytest.approx(expected, abs=1e-4)


@pytest.mark.parametrize("name", sorted(set(COLORS) - set(ARROW_KEYS)))
def test_no_colour_reads_as_a_force_arrow(name):
    for arrow in ARROW_KEYS:
        d = ciede2000(lab(COLORS[name]), lab(COLORS[arrow]))
        assert d >= ARROW_CONTRAST, f"{name} {COLORS[name]:06x} is {d:.1f} from the {arrow} arrow {COLORS[arrow]:06x}"


def test_the_arrows_differ_from_each_other_and_the_old_confusions_are_caught():
    for i, a in enumerate(ARROW_KEYS):
        for b in ARROW_KEYS[i + 1:]:
            assert ciede2000(lab(COLORS[a]), lab(COLORS[b])) >= ARROW_CONTRAST
    # the colours issue 25 found confusable: the sphere and the labels' greens, the pink tissue,
    # the contact line's red, the violet cobot
    for old, arrow in ((0x50B070, "operator"), (0x00A070, "operator"), (0xF04890, "constraint"),
                       (0xD02020, "contact"), (0x6A4FC8, "constraint")):
        assert ciede2000(lab(old), lab(COLORS[arrow])) < ARROW_CONTRAST
