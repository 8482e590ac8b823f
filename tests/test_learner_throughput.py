"""benchmarks/learner_throughput.py's accounting: a case's sequences and frames against a hand
count, its rows (errors and a case cut short included), and the memory check before a run."""

import types

import pytest

from benchmarks import learner_throughput as lt


def test_a_step_of_f_frames_is_f_over_t_sequences_as_the_stream_batches():
    # By hand: T = 1 (VAE_rpl), T = 8 + 16 = 24 (PRED), T = hist = 24 (DSA).
    assert lt.step_shape("VAE_rpl", 1024) == (1024, 1)
    assert lt.step_shape("PRED", 1024) == (42, 24)  # 42 · 24 = 1008 ≤ 1024 < 43 · 24
    assert lt.step_shape("DSA", 256) == (10, 24)
    assert lt.step_shape("DSA", 24) == (1, 24)
    with pytest.raises(ValueError, match="16 frames hold no 24-frame PRED sequence"):
        lt.step_shape("PRED", 16)


def _peer(label, fps=None, error=None):
    t = {"label": label, "version": "2.x", "device": "cuda", "threads": 8}
    return {**t, "error": error} if error else {**t, "first_step_s": 1.0, "fps": fps}


def test_a_case_s_rows_name_sequences_and_frames_and_keep_its_errors():
    case = lt.Case(
        "PRED", 42, 24, "bfloat16", ceiling=100.0, peak=None, gflop_per_frame=0.5, peer_gflop=0.4
    )
    case.jaml = [
        (("auto", "float32"),
         {"compile_s": 3.0, "fps": 2000.0, "xla_gflop_per_frame": 0.1, "temp_gib": 2.5}),
        (("dilated", "float32"), {"error": "out of memory: the compiled step needs 90.0 GiB"}),
        (("auto", "bfloat16"), {"error": "x"}),
    ]
    case.peers = [
        _peer("eager", fps=1000.0),
        _peer("compiled default", error="AssertionError: x"),
        _peer("compiled default, channels_last", fps=1600.0),
    ]
    rows = case.rows()
    assert {r["case"] for r in rows} == {
        "PRED train step, 1008 frames (42 sequences × 24), bfloat16"
    }
    assert {(r["batch"], r["seq_len"], r["frames_per_step"]) for r in rows} == {(42, 24, 1008)}
    assert [r["impl"] for r in rows] == [
        "jaml",
        "jaml, upsample dilated",
        "jaml, bfloat16 activations",
        "pytorch 2.x eager (cuda)",
        "pytorch 2.x compiled default (cuda)",
        "pytorch 2.x compiled default, channels_last (cuda)",
    ]
    assert [r.get("note") for r in rows] == [
        None,
        "out of memory: the compiled step needs 90.0 GiB",
        "x",
        None,
        "AssertionError: x",
        None,
    ]
    assert rows[0]["speedup_vs_pytorch"] == 2000.0 / 1000.0
    assert rows[0]["speedup_vs_pytorch_compiled"] == 2000.0 / 1600.0
    assert rows[0]["useful_tflop_per_s"] == pytest.approx(0.5 * 2000.0 / 1e3)
    assert rows[3]["useful_tflop_per_s"] == pytest.approx(0.5 * 1000.0 / 1e3)  # jaml's count
    assert "speedup_vs_pytorch" not in rows[1]
    # Cut short while a form runs: the rows so far, and an error row for that form.
    case.running = "jaml, upsample phase"
    cut = case.rows(timeout_s=200)
    assert cut[:-1] == rows
    assert cut[-1]["impl"] == "jaml, upsample phase"
    assert cut[-1]["note"] == "did not finish within the case's 200 s (--case-timeout)"
    single = lt.Case("VAE_rpl", 1024, 1, "float32", 100.0, None, 0.67)
    assert single.name == "VAE_rpl train step, batch 1024"  # as before: batch = frames
    assert (
        lt.Case("DSA", 1, 24, "float32", 100.0, None, 0.7).name
        == "DSA train step, 24 frames (1 sequence × 24)"
    )


def test_a_step_that_needs_more_than_the_free_memory_is_refused_with_its_sizes():
    gib = 2**30
    analysis = types.SimpleNamespace(
        temp_size_in_bytes=3 * gib, output_size_in_bytes=gib, alias_size_in_bytes=gib
    )  # needs 3 + 1 − 1 = 3 GiB
    assert lt.memory_shortfall(analysis, {"bytes_limit": 4 * gib, "bytes_in_use": 2 * gib}) == (
        "out of memory: the compiled step needs 3.0 GiB beyond its arguments, 2.0 GiB of the "
        "allocator's 4.0 GiB are free"
    )
    assert lt.memory_shortfall(analysis, {"bytes_limit": 4 * gib, "bytes_in_use": gib}) is None
    assert lt.memory_shortfall(analysis, None) is None  # the CPU: no allocator limit


def test_jaml_s_refused_step_is_an_error_and_is_not_run(monkeypatch):
    """The check sees the compiled step's own memory analysis, and a refusal is the result."""
    seen = []

    def refuse(analysis, stats):
        seen.append(analysis.temp_size_in_bytes)
        return "out of memory: refused"

    monkeypatch.setattr(lt, "memory_shortfall", refuse)
    assert lt.bench_jax(1, 1, 1) == {"error": "out of memory: refused"}
    # VAE_rpl holds a 32×32×64 float32 activation per frame at least.
    assert seen and seen[0] >= 32 * 32 * 64 * 4


def test_svae_has_no_torch_peer_and_gets_jaml_s_rows_alone(monkeypatch, capsys):
    """`--learners DSA SVAE --torch eager`: the peer's variants go to DSA's case, none to
    SVAE's (the peer has no SVAE), and the run says so instead of failing (the peer stubbed:
    its learners and its FLOP count are all the run reads of it before the cases)."""
    peer = types.SimpleNamespace(LEARNERS=("VAE_rpl", "PRED", "DSA"), seq_len=lambda *a: 24,
                                 useful_flops=lambda *a, **k: {"conv": 48e9})
    monkeypatch.setattr(lt, "torch_peer", lambda: peer)
    monkeypatch.setattr(lt, "setup_torch", lambda variants: None)
    seen = {}
    monkeypatch.setattr(lt, "matmul_ceiling", lambda dtype, n: 1.0)
    monkeypatch.setattr(lt, "useful_gflop_per_frame", lambda *a: 1.0)

    def measure_case(case, reps, steps, variants, forms, order, processes):
        seen[case.learner] = variants
        return []

    monkeypatch.setattr(lt, "measure_case", measure_case)
    assert lt.main(["--learners", "DSA", "SVAE", "--frames", "24", "--torch", "eager",
                    "--no-record"]) == 0
    assert seen == {"DSA": [(None, "channels_last")], "SVAE": []}
    assert "SVAE: no PyTorch peer" in capsys.readouterr().out


def test_max_unroll_sets_the_recurrent_layers_cap_and_names_it_in_jaml_s_rows(monkeypatch):
    """`--max-unroll 32` (the rows of an unroll A/B): the cap is set before the case is built
    and jaml's rows say it; the peer's rows are left as they are (measuring stubbed)."""
    from jaml.learners import networks

    monkeypatch.setattr(networks, "_MAX_UNROLL", networks._MAX_UNROLL)  # restored after
    monkeypatch.setattr(lt, "matmul_ceiling", lambda dtype, n: 1.0)
    monkeypatch.setattr(lt, "useful_gflop_per_frame", lambda *a: 1.0)
    caps = []

    def measure_case(case, reps, steps, variants, forms, order, processes):
        caps.append(networks._MAX_UNROLL)
        return [{"impl": "jaml, bfloat16 activations"}, {"impl": "pytorch 2.13 eager (cpu)"}]

    monkeypatch.setattr(lt, "measure_case", measure_case)
    recorded = []
    monkeypatch.setattr(lt.harness, "record", lambda name, rows, notes: recorded.extend(rows))
    assert lt.main(["--learners", "DSA", "--frames", "24", "--torch", "--max-unroll",
                    "32"]) == 0
    assert caps == [32]
    assert [r["impl"] for r in recorded] == ["jaml, bfloat16 activations, unroll ≤ 32",
                                            "pytorch 2.13 eager (cpu)"]
    with pytest.raises(SystemExit):
        lt.main(["--learners", "DSA", "--max-unroll", "0"])


def test_interleaved_sides_take_turns_each_repetition_and_rows_keep_each_ratio(monkeypatch):
    """`--order interleaved`: every side is built before any is timed, then the peer and jaml
    take turns within each repetition; the rows carry each repetition's rate and jaml's the
    range of its per-repetition ratios, against a clock the sides' steps advance by hand."""
    clock, calls, built = [0.0], [], []
    monkeypatch.setattr(lt.time, "perf_counter", lambda: clock[0])
    monkeypatch.setattr(lt, "_peer_running", lambda dtype, mode, fmt: "pytorch 2.x eager (cpu)")
    # Seconds a step takes in each round: the peer 2, 4, 2; jaml 1, 1, 3.
    pace = {"peer": iter([2.0, 4.0, 2.0]), "jaml": iter([1.0, 1.0, 3.0])}

    def side(kind, **info):
        def run_steps(n):
            calls.append(kind)
            clock[0] += n * next(pace[kind])

        @lt.contextlib.contextmanager
        def prepared(*args, **kwargs):
            built.append((kind, list(calls)))
            yield {"run_steps": run_steps, "frames": 10, **info}
            built.append((f"{kind} released", list(calls)))

        return prepared

    monkeypatch.setattr(lt, "torch_prepared", side(
        "peer", label="eager", version="2.x", device="cpu", threads=2, first_step_s=0.1))
    monkeypatch.setattr(lt, "jaml_prepared", side(
        "jaml", compile_s=1.0, xla_gflop_per_frame=0.5, temp_gib=0.1))
    case = lt.Case("VAE_rpl", 10, 1, "float32", ceiling=100.0, peak=None, gflop_per_frame=0.5)
    rows = lt.measure_case(case, 3, 2, [(None, "channels_last")], [("auto", "float32")],
                           order="interleaved")
    assert calls == ["peer", "jaml"] * 3
    assert built[:2] == [("peer", []), ("jaml", [])]  # both built before either is timed
    assert {k for k, _ in built[2:]} == {"peer released", "jaml released"}
    jaml, peer = rows
    assert peer["frames_per_s_rounds"] == [5.0, 2.5, 5.0]  # 10 frames / step seconds
    assert jaml["frames_per_s_rounds"] == pytest.approx([10.0, 10.0, 10.0 / 3])
    assert jaml["speedup_vs_pytorch"] == 10.0 / 5.0  # the medians
    assert jaml["speedup_vs_pytorch_rounds"] == pytest.approx([2.0 / 3, 4.0])
    assert jaml["paired"] == "repetition"
    assert "0.67–4.00× the fastest eager peer per repetition" in lt._lines(rows)
    # One after another (a GPU's way), the rounds are not paired: no per-round ratio.
    pace = {"peer": iter([2.0] * 4), "jaml": iter([1.0] * 4)}
    case = lt.Case("VAE_rpl", 10, 1, "float32", ceiling=100.0, peak=None, gflop_per_frame=0.5)
    calls.clear()
    rows = lt.measure_case(case, 2, 1, [(None, "channels_last")], [("auto", "float32")])
    assert calls == ["peer", "peer", "jaml", "jaml"]
    assert "speedup_vs_pytorch_rounds" not in rows[0]


def test_separate_sides_run_alone_in_processes_taking_turns(monkeypatch):
    """`--order separate` (the CPU's): each side in new processes, the sides' processes taking
    turns; a side's rate is its median process's, each process's rate is a round, and a
    process that fails makes the side an error row."""
    calls = []
    rates = {"peer": iter([100.0, 300.0, 200.0]), "jaml": iter([150.0, 150.0, 450.0])}

    def in_a_process(case, kind, key, reps, steps):
        calls.append((kind, key, reps, steps))
        info = {"label": "eager", "version": "2.x", "device": "cpu", "threads": 2,
                "first_step_s": 0.1} if kind == "peer" else {
            "compile_s": 1.0, "xla_gflop_per_frame": 0.5, "temp_gib": 0.1}
        return {**info, "fps": next(rates[kind]), "rounds": [0.0]}

    monkeypatch.setattr(lt, "_side_in_a_process", in_a_process)
    monkeypatch.setattr(lt, "_peer_running", lambda dtype, mode, fmt: "pytorch 2.x eager (cpu)")
    case = lt.Case("VAE_rpl", 10, 1, "float32", ceiling=100.0, peak=None, gflop_per_frame=0.5)
    jaml, peer = lt.measure_case(case, 5, 2, [(None, "channels_last")], [("auto", "float32")],
                                 order="separate", processes=3)
    assert [c[0] for c in calls] == ["peer", "jaml"] * 3
    assert calls[0] == ("peer", (None, "channels_last"), 5, 2)
    assert peer["frames_per_s"] == 200.0 and peer["frames_per_s_rounds"] == [100.0, 300.0, 200.0]
    assert jaml["frames_per_s"] == 150.0 and jaml["paired"] == "process"
    assert jaml["speedup_vs_pytorch"] == 150.0 / 200.0
    assert jaml["speedup_vs_pytorch_rounds"] == pytest.approx([0.5, 2.25])
    assert lt._across_processes([{"fps": 1.0}, {"error": "x"}]) == {"error": "x"}


def test_a_side_measured_in_its_own_process_comes_back_as_its_result(monkeypatch):
    """The real child: this script with `--side`, jaml's VAE_rpl step on one frame, compiled
    cheaply as this module's own programs are (tests/conftest.py)."""
    monkeypatch.setenv("JAX_DISABLE_MOST_OPTIMIZATIONS", "true")
    case = lt.Case("VAE_rpl", 1, 1, "float32", ceiling=1.0, peak=None, gflop_per_frame=0.5)
    result = lt._side_in_a_process(case, "jaml", ("auto", "float32"), 1, 1)
    assert result["fps"] > 0 and len(result["rounds"]) == 1 and result["compile_s"] > 0
    bad = lt.Case("VAE_rpl", 0, 1, "float32", ceiling=1.0, peak=None, gflop_per_frame=0.5)
    assert "error" in lt._side_in_a_process(bad, "jaml", ("auto", "float32"), 1, 1)
