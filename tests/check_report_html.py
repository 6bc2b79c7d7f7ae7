"""report.html is well-formed and complete (issue 16; docs/outputs.md, "report.html").

    /usr/bin/python3 tests/check_report_html.py OUTPUT_DIR

Well-formed: every element closed in order (HTML5 void elements excepted), one <title>, UTF-8.
Self-contained: no resource outside the page (no http(s) or protocol-relative URL; every image is
embedded PNG data that decodes to a PNG). Complete: every PNG figure of the directory embedded,
the overlay's poster and link when overlay.mp4 exists, each file of the directory linked, the
summary's focal length shown, "not determined" findings and warnings in their boxes when the
summary has them (focal_px null, plane_determined false, figures missing).
"""
import base64
import html.parser
import json
import os
import sys

VOID = {"area", "base", "br", "col", "embed", "hr", "img", "input", "link", "meta", "source", "track", "wbr"}


class Checker(html.parser.HTMLParser):
    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.stack, self.errors, self.images, self.links, self.ids = [], [], [], [], set()
        self.titles = 0
        self.text = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if "id" in a:
            self.ids.add(a["id"])
        if tag == "title":
            self.titles += 1
        if tag == "img":
            self.images.append(a.get("src", ""))
        if tag == "a":
            self.links.append(a.get("href", ""))
        for k in ("src", "href"):
            v = a.get(k, "")
            if v.startswith(("http:", "https:", "//")):
                self.errors.append(f"external resource {v}")
        if tag not in VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if tag in VOID:
            return
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes <{self.stack[-1] if self.stack else 'nothing'}> at line {self.getpos()[0]}")
            return
        self.stack.pop()

    def handle_data(self, data):
        self.text.append(data)


def main(d):
    page = open(os.path.join(d, "report.html"), "rb").read().decode("utf-8")
    s = json.load(open(os.path.join(d, "summary.json")))
    c = Checker()
    c.feed(page)
    c.close()
    errors = list(c.errors)
    if c.stack:
        errors.append(f"unclosed elements: {c.stack}")
    if c.titles != 1:
        errors.append(f"{c.titles} <title> elements")
    if not page.startswith("<!DOCTYPE html>"):
        errors.append("no doctype")
    pngs = 0
    for src in c.images:
        if not src.startswith("data:image/png;base64,"):
            errors.append(f"image not embedded as PNG data: {src[:40]}")
            continue
        if not base64.b64decode(src.split(",", 1)[1]).startswith(b"\x89PNG\r\n\x1a\n"):
            errors.append("an embedded image is not a PNG")
        pngs += 1
    files = sorted(f for f in os.listdir(d) if not f.startswith("."))
    figures = [f for f in files if f.endswith(".png")]
    expected = len(figures) + (1 if "overlay.mp4" in files else 0)
    if pngs != expected:
        errors.append(f"{pngs} embedded images, expected {expected} ({figures} + poster)")
    for f in files:
        if f not in c.links:
            errors.append(f"{f} not linked")
    for l in c.links:
        if not l.startswith("#") and l not in files:
            errors.append(f"link to {l}, which is not in the directory")
    text = " ".join(c.text)
    if s.get("focal_px") is not None and f"{s['focal_px']:.1f}" not in text:
        errors.append(f"focal length {s['focal_px']:.1f} not shown")
    if s.get("focal_px") is None and "not-determined" not in c.ids:
        errors.append("focal length not determined, but no not-determined box")
    if False in s.get("plane_determined", []) and "not-determined" not in c.ids:
        errors.append("a plane not determined, but no not-determined box")
    if s.get("figures", {}).get("missing") and "warnings" not in c.ids:
        errors.append("figures missing, but no warnings box")
    if "overlay.mp4" in files and "overlay.mp4" not in c.links:
        errors.append("overlay.mp4 not linked")
    for section in ("Result", "Figures", "Summary", "Files"):
        if section not in text:
            errors.append(f"no {section} section")
    if errors:
        print(f"report.html in {d}: " + "; ".join(errors))
        return 1
    print(f"report.html in {d}: well-formed, self-contained, {pngs} embedded images, {len(files)} files linked")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
