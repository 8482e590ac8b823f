"""The schedule of runs trained together, against stop sequences computed by hand: analyses,
`stop_after`, runs resumed at different epochs, a deadline's blocks and checks, thinned
checkpoints and non-finite stops."""

import numpy as np

from jaml.stream import schedule
from jaml.stream.schedule import Block


def blocks(epochs, stops, analyses, cap=None):
    """Every block of a call in which no run turns non-finite: the runs advance as told."""
    epochs, out = list(epochs), []
    while (block := schedule.next_block(epochs, stops, analyses, cap)) is not None:
        out.append(block)
        for i in block.runs:
            epochs[i] = block.end
    return out


def test_runs_at_one_epoch_train_together_from_analysis_to_analysis():
    assert blocks([0, 0], [6, 6], [2, 4, 6]) == [
        Block((0, 1), 0, 2, True), Block((0, 1), 2, 4, True), Block((0, 1), 4, 6, True)]


def test_runs_resumed_apart_train_apart_until_an_analysis_they_share():
    # Run 1 resumed at epoch 3: run 0 trains alone to 2 and past 3 to 4; they meet at 4.
    assert blocks([0, 3], [6, 6], [2, 4, 6]) == [
        Block((0,), 0, 2, True), Block((0,), 2, 4, True), Block((1,), 3, 4, True),
        Block((0, 1), 4, 6, True)]


def test_stop_after_ends_each_run_its_own_epochs_into_the_call():
    stops = [schedule.stop_epoch(e, 6, 3) for e in (0, 0)]
    assert stops == [3, 3]
    assert blocks([0, 0], stops, [2, 4, 6]) == [Block((0, 1), 0, 2, True),
                                                Block((0, 1), 2, 3, False)]
    # Resumed apart (run 0 at 1, run 1 at 0), 4 epochs each: together from 2 to run 1's stop at
    # 4, then run 0 alone to its own at 5.
    stops = [schedule.stop_epoch(e, 6, 4) for e in (1, 0)]
    assert stops == [5, 4]
    assert blocks([1, 0], stops, [2, 4, 6]) == [
        Block((1,), 0, 2, True), Block((0,), 1, 2, True), Block((0, 1), 2, 4, True),
        Block((0,), 4, 5, False)]
    assert schedule.stop_epoch(5, 6, 4) == 6 and schedule.stop_epoch(2, 6, None) == 6
    assert blocks([0], [schedule.stop_epoch(0, 6, 0)], [2, 4, 6]) == []


def test_a_deadline_cuts_blocks_at_its_cap_and_keeps_the_analyses():
    """Fig. 2's locomotion schedule (analyses from 78) in the device loop's 32-epoch blocks."""
    assert [(b.start, b.end, b.analysis) for b in blocks([0], [300], [78, 128, 300], cap=32)][:5] \
        == [(0, 32, False), (32, 64, False), (64, 78, True), (78, 110, False), (110, 128, True)]


def test_a_stopped_run_is_left_out_and_none_left_ends_the_call():
    assert schedule.next_block([None, 2], [6, 6], [2, 4, 6]) == Block((1,), 2, 4, True)
    assert schedule.next_block([None, 6], [6, 6], [2, 4, 6]) is None


def test_a_block_starts_only_if_it_ends_before_the_deadline():
    block = Block((0,), 0, 2, True)
    # 2 epochs at 3 s, then the analysis's 4 s: 10 s from now.
    assert schedule.in_time(block, 0.0, 10.0, 3.0, 4.0)
    assert not schedule.in_time(block, 0.0, 10.0, 3.0, 5.0)
    assert schedule.in_time(Block((0,), 0, 2, False), 0.0, 10.0, 3.0, 5.0)
    assert schedule.in_time(block, 9.0, 10.0, None, 4.0)  # no pace yet: only the clock counts
    assert not schedule.in_time(block, 11.0, 10.0, None, 4.0)
    assert schedule.in_time(block, 1e9, None, 3.0, 4.0)


def test_analysis_epochs_start_when_the_replay_is_full():
    assert schedule.analysis_epochs(2, 6, 2) == [2, 4, 6]
    assert schedule.analysis_epochs(2, 7, 4) == [2, 6, 7]
    assert schedule.analysis_epochs(9, 7, 4) == [7]  # ends before the replay fills: the end


def test_thinned_checkpoints_fall_on_the_first_analysis_due_and_the_last():
    """Fig. 2's locomotion schedule: analyses at 78 (replay full), 128, …, 278, 300."""
    analyses = [78, 128, 178, 228, 278, 300]

    def written(every):
        last, out = None, []
        for epoch in analyses:
            if schedule.checkpoint_due(epoch, last, every, last=epoch == analyses[-1]):
                last = epoch
                out.append(epoch)
        return out

    assert written(None) == analyses
    assert written(100) == [128, 228, 300]
    assert written(50) == analyses
    assert written(10_000) == [300]


def test_the_first_non_finite_loss_counts_only_while_the_learner_trains():
    nan, inf = float("nan"), float("inf")
    assert schedule.first_non_finite({"learner/training": np.array([0.0, 1.0, 1.0]),
                                      "learner/loss": np.array([nan, 1.0, inf])}) == 2
    assert schedule.first_non_finite({"learner/training": np.array([0.0, 0.0]),
                                      "learner/loss": np.array([nan, nan])}) is None


def test_a_blocks_checkpoints_are_decided_before_it_trains():
    """Only an analysis at the block's end checkpoints: thinned by `every` from each run's last
    checkpoint, and at the run's last epoch only where `final` asks for it."""
    analysing, between = Block((0, 2), 4, 6, True), Block((0, 2), 3, 5, False)
    last = [4, None, 0]  # run 1 is not in the blocks
    assert schedule.checkpoints(analysing, last, None, 10, True) == [True, True]
    assert schedule.checkpoints(analysing, last, 5, 10, True) == [False, True]
    assert schedule.checkpoints(between, last, None, 10, True) == [False, False]
    assert schedule.checkpoints(analysing, last, 100, 6, True) == [True, True]
    assert schedule.checkpoints(analysing, last, 100, 6, False) == [False, False]


def test_a_run_stopped_here_is_one_whose_stop_ends_the_block_before_its_last_epoch():
    block = Block((0, 1, 2), 2, 4, False)
    assert schedule.stopped_here(block, [4, 6, 4], 4) == [False, False, False]
    assert schedule.stopped_here(block, [4, 6, 4], 10) == [True, False, True]
