"""Re-export an ONNX model with its batch dimension open ("N") on the input
and every output, weights untouched, so the inference stage can run several
cameras' frames through one session.run. Only for models whose nodes do not
fix the batch (convolutions, activations: farsight_train.py's LRN model).

    python tools/train/dynamic_batch.py IN.onnx OUT.onnx
"""
import sys

import onnx


def main(src, dst):
    model = onnx.load(src)
    for v in list(model.graph.input) + list(model.graph.output):
        dim = v.type.tensor_type.shape.dim[0]
        dim.Clear()
        dim.dim_param = "N"
    onnx.checker.check_model(model)
    onnx.save(model, dst)


if __name__ == "__main__":
    main(*sys.argv[1:3])
