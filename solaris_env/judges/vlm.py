"""Optional VLM judge: the paper's exact prompts sent to an OpenAI-compatible vision endpoint.

    python -m solaris_env.judges.evaluate --data DIR --judge vlm --endpoint http://localhost:8000 --model NAME

The paper's judge (docs/engine.md §7.2) called ``gemini-3-flash-preview`` with the system instruction
below, the image(s) as PNG first and the prompt after, and counted an answer correct iff
``answer.strip().lower()`` equals the expected word; 429 responses were tried 3 times (retries after 2 and
4 s) and API errors were left out of the results. Here the same content goes to
``<endpoint>/v1/chat/completions`` (images as base64 ``data:image/png`` URLs, resized to 640x360 like
the reference's ground-truth frames) using only ``urllib``. Off by default; no test talks to a live
endpoint (the request building and response parsing are tested).
"""

from __future__ import annotations

import base64
import json
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from solaris_env.judges import questions

SYSTEM_INSTRUCTION = "You are a helpful assistant that evaluates Minecraft screenshots."
CHAT_PATH = "/v1/chat/completions"


@dataclass(frozen=True, slots=True)
class VLMConfig:
    """Where and how to ask.

    Attributes:
        endpoint: base URL of the server (``http://host:port``) or the full ``.../chat/completions`` URL.
        model: the ``model`` field of the request.
        image_width, image_height: every image is resized to this before PNG encoding.
        timeout_s: per request.
        retry_delays_s: waits before the retries of a 429 / rate-limited request.
        api_key: sent as ``Authorization: Bearer`` when given.
    """

    endpoint: str
    model: str = "gemini-3-flash-preview"
    image_width: int = 640
    image_height: int = 360
    timeout_s: float = 60.0
    retry_delays_s: tuple[float, ...] = (2.0, 4.0)  # 3 attempts in all, as the reference
    api_key: str | None = None

    def __post_init__(self):
        if not self.endpoint.startswith(("http://", "https://")):
            raise ValueError(f"endpoint must be an http(s) URL, got {self.endpoint!r}")
        if self.image_width < 1 or self.image_height < 1:
            raise ValueError(f"image size must be positive, got {self.image_width}x{self.image_height}")

    @property
    def url(self) -> str:
        base = self.endpoint.rstrip("/")
        if base.endswith("/chat/completions"):
            return base
        return base[: -len("/v1")] + CHAT_PATH if base.endswith("/v1") else base + CHAT_PATH


def png_data_url(frame_HW3: np.ndarray, width: int, height: int) -> str:
    """RGB uint8 frame -> ``data:image/png;base64,...`` at width x height."""
    import cv2

    frame_HW3 = np.asarray(frame_HW3)
    if frame_HW3.ndim != 3 or frame_HW3.shape[-1] != 3 or frame_HW3.dtype != np.uint8:
        raise ValueError(f"frame must be uint8 (H, W, 3), got {frame_HW3.dtype} {frame_HW3.shape}")
    if frame_HW3.shape[:2] != (height, width):
        frame_HW3 = cv2.resize(frame_HW3, (width, height), interpolation=cv2.INTER_LINEAR)
    ok, png = cv2.imencode(".png", np.ascontiguousarray(frame_HW3[..., ::-1]))  # RGB -> BGR for OpenCV
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return "data:image/png;base64," + base64.b64encode(png.tobytes()).decode("ascii")


def build_payload(question: str, frames: Sequence[np.ndarray], cfg: VLMConfig) -> dict:
    """The chat-completions body: system instruction, then one user turn with the images and the prompt."""
    q = questions.get(question)
    if len(frames) != q.num_frames:
        raise ValueError(f"{question} takes {q.num_frames} image(s), got {len(frames)}")
    content = [{"type": "image_url", "image_url": {"url": png_data_url(f, cfg.image_width, cfg.image_height)}}
               for f in frames]
    content.append({"type": "text", "text": q.prompt})
    return {"model": cfg.model, "messages": [{"role": "system", "content": SYSTEM_INSTRUCTION},
                                             {"role": "user", "content": content}]}


def build_request(question: str, frames: Sequence[np.ndarray], cfg: VLMConfig) -> urllib.request.Request:
    headers = {"Content-Type": "application/json"}
    if cfg.api_key:
        headers["Authorization"] = f"Bearer {cfg.api_key}"
    body = json.dumps(build_payload(question, frames, cfg)).encode("utf-8")
    return urllib.request.Request(cfg.url, data=body, headers=headers, method="POST")


def parse_response(body: dict) -> str:
    """The answer text of a chat-completions response, ``strip().lower()`` (text parts joined)."""
    try:
        content = body["choices"][0]["message"]["content"]
    except (KeyError, IndexError, TypeError):
        raise ValueError(f"not a chat-completions response: {str(body)[:200]}") from None
    if isinstance(content, list):
        content = "".join(part.get("text", "") for part in content if isinstance(part, dict))
    if not isinstance(content, str):
        raise ValueError(f"message content is {type(content).__name__}, expected text")  # noqa: TRY004 - bad data
    return content.strip().lower()


class VLMJudge:
    """Same interface as :class:`Judge`; an answer is None when the API failed (left out of the scores).

    Args:
        cfg: endpoint and request settings.
        sleep: called with the delay before a retry (tests pass a stub).
    """

    def __init__(self, cfg: VLMConfig, sleep: Callable[[float], None] = time.sleep):
        self.cfg = cfg
        self._sleep = sleep

    def ask(self, question: str, frames: Sequence[np.ndarray]) -> str | None:
        request = build_request(question, frames, self.cfg)
        for attempt in range(len(self.cfg.retry_delays_s) + 1):
            try:
                with urllib.request.urlopen(request, timeout=self.cfg.timeout_s) as resp:
                    return parse_response(json.loads(resp.read().decode("utf-8")))
            except urllib.error.HTTPError as e:
                if e.code != 429 or attempt == len(self.cfg.retry_delays_s):
                    print(f"vlm judge: HTTP {e.code} for {question}: {e.reason}", file=sys.stderr)
                    return None
                self._sleep(self.cfg.retry_delays_s[attempt])
            except (urllib.error.URLError, TimeoutError, ValueError, json.JSONDecodeError) as e:
                print(f"vlm judge: {question}: {e}", file=sys.stderr)
                return None
        return None

    def answer(self, question: str, *frames) -> list[str | None]:
        batches = [np.asarray(f) for f in frames]
        batches = [b[None] if b.ndim == 3 else b for b in batches]
        if len({len(b) for b in batches}) > 1:
            raise ValueError(f"{question}: frame batches differ in length: {[len(b) for b in batches]}")
        n = len(batches[0]) if batches else 0
        return [self.ask(question, [b[i] for b in batches]) for i in range(n)]
