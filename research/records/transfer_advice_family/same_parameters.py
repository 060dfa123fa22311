"""Whether two saved 4-agent teams hold the same parameters, tensor for tensor.

python docs/results/transfer_advice_family/same_parameters.py RUN_A RUN_B
"""

import io
import sys
import zipfile

import torch as th

first, second = sys.argv[1], sys.argv[2]
identical = True
for i in range(4):
    tensors = [
        th.load(
            io.BytesIO(zipfile.ZipFile(f"{run}/team/agent_{i}.zip").read("policy.pth")), map_location="cpu"
        )
        for run in (first, second)
    ]
    same = tensors[0].keys() == tensors[1].keys() and all(
        th.equal(tensors[0][k], tensors[1][k]) for k in tensors[0]
    )
    print(f"agent_{i}: {len(tensors[0])} tensors, identical: {same}")
    identical &= same
print("ALL IDENTICAL" if identical else "DIFFERENT")
