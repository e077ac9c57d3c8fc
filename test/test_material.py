"""Issue 12 part 6: the FEM cantilever reference and the alpha fit (sm_ros.bench.material)."""

import math

import pytest

from sm_ros.bench import material as mat


def test_fem_cantilever_matches_beam_theory():
    """Linear-elastic FEM (scikit-fem) against Euler-Bernoulli for the slender beam."""
    pytest.importorskip('skfem', reason='the fem extra (scikit-fem) is not installed')
    young = 1e6
    sag, f1 = mat.fem_reference(nu=0.3, cells=12, young=young)
    rho = mat.MASS / (mat.LENGTH * mat.WIDTH ** 2)
    inertia = mat.WIDTH ** 4 / 12.0
    area = mat.WIDTH ** 2
    sag_eb = rho * area * mat.G * mat.LENGTH ** 4 / (8.0 * young * inertia)
    f_eb = 1.875 ** 2 / (2.0 * math.pi) * math.sqrt(young * inertia / (rho * area
                                                                      * mat.LENGTH ** 4))
    assert sag == pytest.approx(sag_eb, rel=0.03)     # measured +0.8 % (shear)
    assert f1 == pytest.approx(f_eb, rel=0.03)        # measured -1.1 %
    sag2, f2 = mat.fem_reference(nu=0.3, cells=12, young=4.0 * young)
    assert sag2 == pytest.approx(sag / 4.0, rel=1e-9)   # linear: sag ~ 1/E, f ~ sqrt(E)
    assert f2 == pytest.approx(2.0 * f1, rel=1e-9)


def test_fit_alpha_recovers_the_alpha_of_a_sag():
    params = {'mode': 'linear', 'alpha': 0.1, 'beta': 0.5, 'clusters': 1}
    target = mat.static_sag(params, 0.05)
    alpha, sag = mat.fit_alpha(target, 'linear', 1, 0.05, beta=0.5)
    assert alpha == pytest.approx(0.1, rel=0.02)
    assert sag == pytest.approx(target, rel=0.01)
    # stiffer than alpha = 1 can give: unreachable, reported with the sag at alpha = 1
    alpha, stiffest = mat.fit_alpha(0.5 * mat.static_sag(dict(params, alpha=1.0), 0.05),
                                    'linear', 1, 0.05)
    assert alpha is None and stiffest > 0.0
