"""Make ``frames_h264.mp4``: 40 frames of 720×576 H.264 (B-frames, a keyframe every 12 frames).

OpenCV's bundled FFmpeg decodes H.264 but cannot encode it, so this fixture is
committed; it was made with PyAV (which bundles libx264), not a test dependency:

    pip install av && python tests/data/make_h264_fixture.py

Frame ``i`` is dark with a bright 8-pixel column at ``u = 16 i`` and a bright
row at ``v = 8 + 4 i``, so the frame a reader returns tells its own index.
"""

from pathlib import Path

import av
import numpy as np

N_FRAMES, WIDTH, HEIGHT = 40, 720, 576


def frame(i: int) -> np.ndarray:
    image = np.full((HEIGHT, WIDTH), 16, dtype=np.uint8)
    image[:, 16 * i : 16 * i + 8] = 235
    image[8 + 4 * i : 12 + 4 * i, :] = 235
    return image


def main() -> None:
    out = Path(__file__).with_name("frames_h264.mp4")
    with av.open(str(out), "w") as container:
        stream = container.add_stream("libx264", rate=25)
        stream.width, stream.height, stream.pix_fmt = WIDTH, HEIGHT, "yuv420p"
        stream.options = {"g": "12", "bf": "2", "crf": "18"}
        for i in range(N_FRAMES):
            video_frame = av.VideoFrame.from_ndarray(frame(i), format="gray")
            container.mux(stream.encode(video_frame))
        container.mux(stream.encode())
    print(f"wrote {out} ({out.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
