"""covviz.experiments.losses: each loss's recovery, size and offset from the boxes, and where losses recur."""

import numpy as np
import pytest

from covviz.experiments.losses import FOUND_IOU, Loss, describe_losses, recurring


def _truth(n=40):
    g = np.zeros((n, 4))
    g[:, 0] = 100 + np.arange(n)  # moving right, 1 px a frame
    g[:, 1] = 50
    g[:, 2:] = 20
    return g


def test_a_slide_off_and_back_is_found_again_with_its_offset():
    g = _truth()
    b = g.copy()
    b[10:15, 0] += 40  # two sizes to the right on frames 11-15 (1-based), back on 16
    (loss,) = describe_losses(b, g)
    assert loss.lost_at == 11 and loss.drift_began == 11 and loss.drift_frames == 0  # a jump: lost as it began
    assert loss.found_again == 16 and loss.frames_lost == 5
    assert loss.size_ratio == pytest.approx(1.0)
    assert loss.centre_offset == pytest.approx(2.0)


def test_a_box_grown_around_the_target_is_on_the_spot_and_never_found():
    g = _truth()
    b = g.copy()
    k = np.arange(1, 31)
    grow = 1.1 ** k  # from frame 2 on, 10% a frame, centred on the truth
    b[1:31, 2] = 20 * grow
    b[1:31, 3] = 20 * grow
    b[1:31, 0] = g[1:31, 0] + 10 - b[1:31, 2] / 2
    b[1:31, 1] = g[1:31, 1] + 10 - b[1:31, 3] / 2
    b[31:] = b[30]  # stays grown
    (loss,) = describe_losses(b, g)
    i = loss.lost_at - 1
    # IoU of a centred box s times the truth's side is 1 / s^2: below 0.1 from s > sqrt(10)
    assert np.sqrt(b[i - 1, 2] * b[i - 1, 3]) / 20 <= np.sqrt(10) < np.sqrt(b[i, 2] * b[i, 3]) / 20
    assert loss.size_ratio == pytest.approx(b[i, 2] / 20)
    assert loss.centre_offset < 0.75
    assert loss.found_again is None and loss.frames_lost is None
    # the event detector's onset: the IoU has been falling since frame 2, where the growth began
    assert loss.drift_began == 2 and loss.lost_at == 14  # 1.1^13 = 3.45 > sqrt(10) >= 1.1^12
    assert loss.drift_frames == 12  # a slow slide: twelve frames from its start to the loss


def test_missing_truth_is_never_the_frame_found_again():
    g = _truth()
    b = g.copy()
    b[10:15, 0] += 40
    g[15:18] = np.nan  # frames 16-18 have no truth
    (loss,) = describe_losses(b, g)
    assert loss.found_again == 19
    assert FOUND_IOU == 0.5


def test_no_loss_and_bad_shapes():
    g = _truth()
    assert describe_losses(g, g) == []
    with pytest.raises(ValueError, match="same length|both be"):
        describe_losses(g[:-1], g)
    with pytest.raises(ValueError, match="both be"):
        describe_losses(g[:, :3], g[:, :3])


def _loss(at):
    return Loss(at, at, None, 1.0, 3.0)


def test_recurring_places_count_each_seed_once_and_come_most_seeds_first():
    per_seed = {
        0: [_loss(71), _loss(73), _loss(200)],  # two losses in one place count the seed once
        1: [_loss(75)],
        2: [_loss(79), _loss(203)],
        3: [_loss(205)],
        4: [_loss(30)],
        5: [],
    }
    assert recurring(per_seed) == [(71, 79, 3), (200, 205, 3)]
    assert recurring(per_seed, min_share=0.6) == []  # 3 of 6 seeds < 0.6
    # a window shorter than a place's spread finds its densest part only; ties go to the earlier window
    assert recurring(per_seed, window=3) == [(73, 75, 2), (203, 205, 2)]
    assert recurring({}) == []
    with pytest.raises(ValueError, match="window"):
        recurring(per_seed, window=0)


def test_early_warning_script_splits_jumps_from_slides_and_times_the_evidence(tmp_path, capsys):
    """scripts/early_warning.py on a bench folder of one run: a slide (drift 11, lost 16) and a jump (31, 31)."""
    import importlib.util
    import json
    from pathlib import Path

    iou = np.full(40, 0.8)
    iou[10:16] = [0.7, 0.6, 0.45, 0.3, 0.2, 0.05]  # frames 11-16: the slide
    iou[16:20] = 0.05
    iou[30:] = 0.02  # frame 31: the jump
    colour = np.zeros(40)
    colour[12:] = 1.0  # above 0.8 from frame 13: 3 frames before the slide's loss
    colour[30:] = 0.0
    p = [None] * 40  # the drift probability missing everywhere: never true
    run = {"tracker": "manifold", "seed": 0,
           "diagnosis": {"frame_iou": iou.tolist(), "signals": {"colour": colour.tolist()}, "drift_probability": p}}
    (tmp_path / "Seq").mkdir()
    (tmp_path / "Seq" / "manifold_s0.json").write_text(json.dumps(run))
    path = Path(__file__).resolve().parents[1] / "scripts" / "early_warning.py"
    spec = importlib.util.spec_from_file_location("early_warning", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main([str(tmp_path), "colour > 0.8", "p > 0.5"]) == 0
    out = capsys.readouterr().out
    assert "2 losses in 1 runs; 1 jumps" in out and "1 slides" in out
    assert "| `colour > 0.8` | 1 of 1 | 3 |" in out
    assert "| `p > 0.5` | 0 of 1 | — |" in out
    assert "| Seq | manifold_s0 | 11 | 16 | 3 | · |" in out
    assert mod.main([str(tmp_path / "none")]) == 2
