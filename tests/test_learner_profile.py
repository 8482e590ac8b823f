"""The profile's kernel kinds, on names taken from an H100 trace of a train step."""

from benchmarks.learner_profile import kind_of, summarise


def test_kernels_are_sorted_by_their_op_or_their_fusion_name():
    cudnn = "void cask_plugin__5x_cudnn::xmma__5x_cudnn::init_device_workspace_kernel<x>"
    assert kind_of("cudnn-conv-bw-filter.8", cudnn) == "convolution"
    assert kind_of("cudnn-conv.58", "sm90_xmma_fprop_implicit_gemm_bf16bf16") == "convolution"
    assert kind_of("cudnn-conv.39", "Memset 3") == "memset/memcpy"
    assert kind_of("command_buffer_260", "input_add_reduce_fusion_4") == "reduction fusion"
    assert kind_of("command_buffer_86", "input_concatenate_fusion_2") == "reduction fusion"
    assert kind_of("command_buffer_245", "loop_add_fusion_2") == "elementwise fusion"
    assert kind_of("command_buffer_210", "gemm_fusion_dot_3") == "matmul"
    assert kind_of("command_buffer_607", "wrapped_transpose_6") == "transpose/copy"
    assert kind_of("command_buffer_124", "memcpy32_post") == "memset/memcpy"
    assert kind_of("", "some_kernel") == "other"


def test_an_op_s_kernels_are_summed_by_kind():
    kernels = [("cudnn-conv.14", "Memset 3", 0.001), ("cudnn-conv.14", "sm90_xmma_fprop", 0.003),
               ("cudnn-conv.14", "sm90_xmma_fprop", 0.002),
               ("command_buffer_9", "loop_add_fusion", 0.004)]
    s = summarise(kernels, steps=2, wall_s=0.02)
    assert s["busy_ms_per_step"] == 5.0 and s["wall_ms_per_step"] == 10.0
    assert s["by_kind_ms_per_step"] == {"convolution": 2.5, "elementwise fusion": 2.0,
                                        "memset/memcpy": 0.5}
    assert [(o["op"], o["kind"], o["ms_per_step"]) for o in s["top_ops"]] == [
        ("cudnn-conv.14", "convolution", 2.5), ("loop_add_fusion", "elementwise fusion", 2.0),
        ("cudnn-conv.14", "memset/memcpy", 0.5)]
