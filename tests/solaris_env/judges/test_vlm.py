"""The optional VLM judge: request building (the paper's prompts, images first, base64 PNG), response
parsing, and the HTTP client against a local OpenAI-style stub server (never a live VLM)."""

import base64
import json
import threading
from http.server import BaseHTTPRequestHandler, HTTPServer

import cv2
import numpy as np
import pytest

from solaris_env.engine.eval_protocol import PROMPTS
from solaris_env.judges import questions
from solaris_env.judges.vlm import (
    SYSTEM_INSTRUCTION,
    VLMConfig,
    VLMJudge,
    build_payload,
    build_request,
    parse_response,
    png_data_url,
)


def frame(seed, h=64, w=64):
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def decode(url):
    head, b64 = url.split(",", 1)
    assert head == "data:image/png;base64"
    return cv2.imdecode(np.frombuffer(base64.b64decode(b64), np.uint8), cv2.IMREAD_COLOR)[..., ::-1]


def test_endpoint_urls_are_normalised():
    assert VLMConfig("http://h:8000").url == "http://h:8000/v1/chat/completions"
    assert VLMConfig("http://h:8000/v1/").url == "http://h:8000/v1/chat/completions"
    assert VLMConfig("https://h/api/v1/chat/completions").url == "https://h/api/v1/chat/completions"
    with pytest.raises(ValueError, match="endpoint must be an http"):
        VLMConfig("h:8000")


@pytest.mark.parametrize("question", sorted(questions.QUESTIONS))
def test_payload_has_the_papers_prompt_after_the_images(question):
    q = questions.get(question)
    cfg = VLMConfig("http://h", model="m")
    frames = [frame(k) for k in range(q.num_frames)]
    body = build_payload(question, frames, cfg)
    assert body["model"] == "m"
    system, user = body["messages"]
    assert system == {"role": "system", "content": SYSTEM_INSTRUCTION}
    *images, text = user["content"]
    assert text == {"type": "text", "text": PROMPTS[q.prompt_key]}
    assert len(images) == q.num_frames
    for img, f in zip(images, frames):
        got = decode(img["image_url"]["url"])
        assert got.shape == (cfg.image_height, cfg.image_width, 3)
        want = cv2.resize(f, (cfg.image_width, cfg.image_height), interpolation=cv2.INTER_LINEAR)
        np.testing.assert_array_equal(got, want)  # PNG is lossless: exactly the resized frame


def test_png_keeps_a_frame_of_the_target_size_unchanged():
    f = frame(3, 360, 640)
    np.testing.assert_array_equal(decode(png_data_url(f, 640, 360)), f)
    with pytest.raises(ValueError, match="uint8"):
        png_data_url(f.astype(np.float32), 640, 360)


def test_request_is_a_json_post_with_optional_bearer_key():
    req = build_request("visible", [frame(0)], VLMConfig("http://h:1", api_key="k"))
    assert req.get_method() == "POST" and req.full_url == "http://h:1/v1/chat/completions"
    assert req.get_header("Authorization") == "Bearer k" and req.get_header("Content-type") == "application/json"
    assert json.loads(req.data)["messages"][1]["content"][-1]["text"] == PROMPTS["one_looks_away"]
    assert build_request("visible", [frame(0)], VLMConfig("http://h:1")).get_header("Authorization") is None
    with pytest.raises(ValueError, match="takes 2 image"):
        build_request("motion", [frame(0)], VLMConfig("http://h:1"))


def test_parse_response_normalises_like_the_reference():
    assert parse_response({"choices": [{"message": {"content": "  Left.\n"}}]}) == "left."
    assert parse_response({"choices": [{"message": {"content": [{"type": "text", "text": "No "},
                                                                  {"type": "text", "text": "Player"}]}}]}) == "no player"
    with pytest.raises(ValueError, match="not a chat-completions response"):
        parse_response({"error": "x"})


class StubServer:
    """A local OpenAI-style endpoint: answers ``reply``, after ``fail_first`` 429 responses."""

    def __init__(self, reply, fail_first=0):
        self.requests, self.fail_left = [], fail_first
        stub = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                stub.requests.append((self.path, body))
                if stub.fail_left > 0:
                    stub.fail_left -= 1
                    self.send_response(429)
                    self.end_headers()
                    return
                out = json.dumps({"choices": [{"message": {"role": "assistant", "content": reply}}]}).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(out)))
                self.end_headers()
                self.wfile.write(out)

            def log_message(self, *args):
                pass

        self.server = HTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_port}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self):
        self.server.shutdown()
        self.server.server_close()


def test_vlm_judge_round_trip_and_429_retries():
    server = StubServer("Closer", fail_first=2)
    try:
        slept = []
        judge = VLMJudge(VLMConfig(server.url, timeout_s=5), sleep=slept.append)
        first, second = np.stack([frame(0), frame(1)]), np.stack([frame(2), frame(3)])
        assert judge.answer("motion", first, second) == ["closer", "closer"]
        assert slept == [2.0, 4.0]  # the reference's retry delays
        assert len(server.requests) == 4 and all(p == "/v1/chat/completions" for p, _ in server.requests)
        server.fail_left = 3  # more 429s than retries: the query is left unanswered
        assert judge.answer("visible", frame(0)) == [None]
    finally:
        server.close()


def test_unreachable_endpoint_gives_unanswered_queries():
    server = StubServer("yes")
    url = server.url
    server.close()
    assert VLMJudge(VLMConfig(url, timeout_s=2)).answer("visible", frame(0)) == [None]
