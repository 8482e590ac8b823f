"""The profile's kernel kinds and layers, on names taken from traces and compiled steps."""

from benchmarks.learner_profile import by_layer, kind_of, layer_of_op, op_names, summarise


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
    assert kind_of("loop_convert_select_fusion_1", "loop_convert_select_fusion_1") == \
        "elementwise fusion"
    assert kind_of("input_convert_reduce_fusion", "input_convert_reduce_fusion") == \
        "reduction fusion"


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


def test_a_kernel_is_placed_in_the_layer_its_op_came_from():
    layers = {"conv/conv1", "conv/conv_out", "decoder/deconv2", "trunk/dense0",
              "dynamic_rnn/bilstm/RNN_0/OptimizedLSTMCell_0"}
    root = "jit(step)/transpose(jvp(FeedForwardVAE))/FeedForwardVAE.posterior"
    assert layer_of_op(f"{root}/conv/conv1/conv_general_dilated", layers) == ("conv/conv1", True)
    assert layer_of_op("jit(step)/jvp(FeedForwardVAE)/FeedForwardVAE.posterior/conv/bn1/"
                       "reduce_sum", layers) == ("conv/conv1", False)  # the conv before it
    assert layer_of_op(f"{root}/conv/bn_out/mul", layers) == ("conv/conv_out", True)
    assert layer_of_op("jit(step)/jvp(VAE)/VAE.decode/decoder/bn2/add", layers) == (
        "decoder/deconv2", False)
    assert layer_of_op(f"{root}/conv/mul", layers) == ("conv (other)", True)
    assert layer_of_op("jit(step)/jvp(DSA)/DSA.encode/dynamic_rnn/bilstm/RNN_0/"
                       "OptimizedLSTMCell_0.scan_fn/dot_general", layers) == (
        "dynamic_rnn/bilstm/RNN_0/OptimizedLSTMCell_0", False)
    assert layer_of_op("jit(step)/add", layers) == ("(other)", False)


def test_kernels_are_summed_by_the_layer_of_their_op():
    hlo = ('  %cudnn-conv.14 = (bf16[8]{0}, u8[0]{0}) custom-call(), metadata={op_type="conv" '
           'op_name="jit(step)/jvp(VAE)/VAE.posterior/conv/conv1/conv_general_dilated"}\n'
           '  ROOT %input_add_reduce_fusion.3 = f32[8]{0} fusion(), metadata={op_name='
           '"jit(step)/transpose(jvp(VAE))/VAE.posterior/conv/bn1/reduce_sum" source_line=3}\n')
    names = op_names(hlo)
    assert names == {
        "cudnn-conv.14": "jit(step)/jvp(VAE)/VAE.posterior/conv/conv1/conv_general_dilated",
        "input_add_reduce_fusion.3": "jit(step)/transpose(jvp(VAE))/VAE.posterior/conv/bn1/"
                                     "reduce_sum"}
    # A kernel's op writes "_" for the instruction's "."; in a CUDA graph the kernel names it.
    kernels = [("cudnn-conv.14", "fprop", 0.003), ("cudnn-conv.14", "Memset", 0.001),
               ("input_add_reduce_fusion_3", "input_add_reduce_fusion_3", 0.002),
               ("command_buffer_9", "input_add_reduce_fusion_3", 0.002),
               ("command_buffer_9", "loop_add_fusion", 0.004)]
    assert by_layer(kernels, names, {"conv/conv1"}, steps=2) == {
        ("conv/conv1", False): 2.0, ("conv/conv1", True): 2.0, ("(not placed)", False): 2.0}
