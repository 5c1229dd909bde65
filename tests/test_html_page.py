"""html_page.render: a report's markdown as one self-contained page."""

import base64
import re

from inertia_gym.html_page import render

PNG = base64.b64decode("iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNk+M9QDwADhgGAWjR9aw"
                       "AAAABJRU5ErkJggg==")  # a 1x1 PNG


def test_each_markdown_form_of_a_summary_is_rendered_and_escaped(tmp_path):
    (tmp_path / "residuals.png").write_bytes(PNG)
    text = "\n".join([
        "# Diagnosis of r", "", "## Verdict", "", "The model misses **physics**: `viscous_damping`,",
        "taking x < 2.", "", "- one", "- two <b>", "", "| effect | value |", "|---|---|",
        "| drag | 1e-6 |", "| bias | 2 |", "", "```", "raw <line>", "```", "",
        "![residuals.png](residuals.png)", "![spectrum.png](spectrum.png)"])
    page = render(text, tmp_path, "Diagnosis of r")
    assert "<h1>Diagnosis of r</h1>" in page and "<h2>Verdict</h2>" in page
    assert ("<p>The model misses <strong>physics</strong>: <code>viscous_damping</code>, taking x &lt; 2.</p>"
            in page)
    assert "<ul><li>one</li><li>two &lt;b&gt;</li></ul>" in page
    assert "<tr><th>effect</th><th>value</th></tr>" in page and page.count("<tr>") == 3
    assert "<pre>raw &lt;line&gt;</pre>" in page
    assert f'src="data:image/png;base64,{base64.b64encode(PNG).decode()}"' in page
    assert "spectrum.png (not written)" in page


def test_the_page_refers_to_no_other_file(tmp_path):
    (tmp_path / "a.png").write_bytes(PNG)
    page = render("# t\n\n![a.png](a.png)\n", tmp_path, "t")
    assert all(src.startswith("data:") for src in re.findall(r'src="([^"]*)"', page))
    assert "<link" not in page and "<script" not in page
