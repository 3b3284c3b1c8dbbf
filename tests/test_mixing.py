import pytest

from miktcli.methods.mixing import mixing_series


def rows(**columns):
    return [{"steps": 2048 * (i + 1), **{k: v[i] for k, v in columns.items()}} for i in range(2)]


def test_one_teacher_gets_one_minus_the_student_weight():
    series = mixing_series(rows(p_pi_0=[0.4, 0.9], p_vf_0=[0.5, 1.0], loss_mi=[1.0, 2.0]), ["four"])
    assert list(series) == ["policy", "value"]
    assert series["policy"]["layer 0 student"] == [(2048, 0.4), (4096, 0.9)]
    assert series["policy"]["layer 0 four"] == [(2048, pytest.approx(0.6)), (4096, pytest.approx(0.1))]
    assert series["value"]["layer 0 four"][1] == (4096, 0.0)


def test_each_teacher_in_card_order_and_the_shared_share():
    per = mixing_series(rows(p_pi_0=[0.3, 0.5], w_pi_0_t0=[0.3, 0.2], w_pi_0_t1=[0.4, 0.3],
                             p_pi_1=[0.2, 0.2], w_pi_1_t0=[0.4, 0.4], w_pi_1_t1=[0.4, 0.4]), ["four", "six"])
    assert list(per["policy"]) == ["layer 0 student", "layer 0 four", "layer 0 six",
                                   "layer 1 student", "layer 1 four", "layer 1 six"]
    assert per["policy"]["layer 0 six"] == [(2048, 0.4), (4096, 0.3)]
    shared = mixing_series(rows(p_vf_0=[0.47, 0.6], w_vf_0_shared=[0.53, 0.4]), ["four", "six"])
    assert shared == {"value": {"layer 0 student": [(2048, 0.47), (4096, 0.6)],
                                "layer 0 four + six (shared)": [(2048, 0.53), (4096, 0.4)]}}


def test_no_mixing_weights_no_series():
    assert mixing_series(rows(return_mean=[1.0, 2.0]), []) == {}
