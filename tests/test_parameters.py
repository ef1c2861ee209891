import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dualid.errors import ModelError
from dualid.model.parameters import ParameterBlock, ParameterSpace, pseudo_inertia_basis, rigid_body_space
from tests.factories import box_inertia


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_pseudo_inertia_basis_matches_pinocchio(seed):
    inertia = box_inertia(np.random.default_rng(seed))  # drawn from the seed, so a failure reproduces
    theta = inertia.toDynamicParameters()
    P = np.tensordot(theta, pseudo_inertia_basis(), axes=1)
    np.testing.assert_allclose(P, inertia.toPseudoInertia().toMatrix(), atol=1e-12)


def test_consistency_of_rigid_body_blocks():
    space = rigid_body_space(["link"])
    good = box_inertia(np.random.default_rng(3)).toDynamicParameters()
    assert space.is_consistent(good)
    bad = good.copy()
    bad[0] = -1.0  # negative mass
    assert not space.is_consistent(bad)
    # triangle inequality violated: Ixx > Iyy + Izz about the CoM
    violating = pin.Inertia(1.0, np.zeros(3), np.diag([3.0, 1.0, 1.0])).toDynamicParameters()
    assert not space.is_consistent(violating)
    assert space.consistency_margins(violating)["link"] < 0


def test_block_and_space_errors_are_explicit():
    with pytest.raises(ValueError, match=r"block 'b': a rigid_body block has 10 parameters, got 3"):
        ParameterBlock("b", "rigid_body", (0, 1, 2))
    with pytest.raises(ValueError, match=r"kind must be one of .* got 'viscous'"):
        ParameterBlock("b", "viscous", (0,))
    with pytest.raises(ValueError, match=r"ParameterSpace: 2 names but 1 units"):
        ParameterSpace(("a", "b"), ("kg",))
    with pytest.raises(ValueError, match=r"duplicate parameter names \['a'\]"):
        ParameterSpace(("a", "a"), ("kg", "kg"))
    with pytest.raises(ValueError, match=r"block 'x': parameters \[0\] already in another block"):
        ParameterSpace(("a",), ("kg",), (ParameterBlock("w", "nonnegative", (0,)), ParameterBlock("x", "free", (0,))))
    with pytest.raises(ModelError, match=r"^no parameter named 'c'; parameters are \['a'\]$"):
        ParameterSpace(("a",), ("kg",)).index("c")


def test_bounds_and_concatenation():
    a = rigid_body_space(["l1"])
    b = ParameterSpace(("fv",), ("N m s",), (ParameterBlock("friction", "nonnegative", (0,)),))
    ab = a.concatenate(b).with_bounds(upper={"l1.m": 2.0})
    assert ab.p == 11 and ab.blocks[1].indices == (10,)
    theta = np.concatenate([pin.Inertia(1.0, np.zeros(3), np.eye(3)).toDynamicParameters(), [0.1]])
    assert ab.is_consistent(theta)
    theta[0] = 3.0
    assert not ab.is_consistent(theta)  # above the mass bound
