"""Drives optistim's SurRender endpoint with the SurRender client exactly as published
(../shared/clients/surrender, unchanged): set-up, the poses of a JSON file, image retrieval.
Called by tests/surrender.rs:  python surrender_drive.py PORT POSES.json OUT.npz

The published client compares types with np.float and np.int, which NumPy removed in 1.24:
it runs on NumPy < 1.24 (.ci/run installs numpy 1.23.5 in its venv)."""
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
CLIENT = os.path.join(HERE, "..", "..", "..", "shared", "clients", "surrender")
sys.path.insert(0, os.path.abspath(CLIENT))
from surrender.surrender_client import surrender_client  # noqa: E402

port, poses_file, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
job = json.load(open(poses_file))

s = surrender_client()
s.setVerbosityLevel(1)
s.connectToServer("127.0.0.1", port)
version = s.version()
s.setImageSize(job["width"], job["height"])
s.setCameraFOVDeg(job["fov_deg"][0], job["fov_deg"][1])
s.setIntegrationTime(job["exposure_s"])

images, depths, rgba = [], [], []
for p in job["poses"]:
    q = p["q_wxyz"]
    if p["convention"] == "scalar_first_z_front":
        s.setConventions(s.SCALAR_XYZ_CONVENTION, s.Z_FRONTWARD)
        att = q
    else:
        # x, y, z, w of the attitude of an OpenGL camera (Z backward, Y up).
        s.setConventions(s.XYZ_SCALAR_CONVENTION, s.Z_BACKWARD)
        att = p["q_gl_xyzw"]
    s.setObjectPosition("camera", p["camera_m"])
    s.setObjectAttitude("camera", att)
    s.setObjectPosition("sun", p["sun_m"])
    s.render()
    images.append(s.getImageGray32F())
depths.append(s.getDepthMap())
rgba.append(s.getImage())
s.setCompressionLevel(6)
compressed = s.getImageGray32F()
state = s.getState()

# A call optistim does not serve: a clear error naming it, and the connection stays.
refused = ""
try:
    s.createBody("moon2", "sphere", "lambert", [])
    s.getImageSize()
except RuntimeError as e:
    refused = str(e)
after = s.getImageSize()

np.savez(
    out,
    images=np.array(images),
    depth=depths[0],
    rgba=rgba[0],
    compressed=compressed,
    version=version,
    state=state,
    refused=refused,
    after=np.array(after),
)
print("driven", len(images), "poses;", version)
