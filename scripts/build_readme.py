"""Assemble README.md from the sections in docs/readme/ (one file per subsystem, kept next to its owner's notes).

    python scripts/build_readme.py

Order: intro, tour, env, then the subsystems from the sky to the controller, reliability, performance, papers.
Image links inside the sections are written relative to docs/readme/ and rewritten for the top level.
"""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ORDER = [
    "00_intro.md", "05_tour.md", "env.md", "06_policies.md", "imaging.md", "identify.md", "tracking.md", "dynamics.md",
    "color.md", "multifov.md", "90_reliability.md", "performance.md", "99_papers.md",
]


def main() -> None:
    parts = []
    for name in ORDER:
        p = ROOT / "docs" / "readme" / name
        if not p.exists():
            continue
        text = p.read_text().strip()
        text = text.replace("](../", "](docs/").replace("](../../", "](")
        parts.append(text)
    (ROOT / "README.md").write_text("\n\n".join(parts) + "\n")
    print(f"README.md: {sum(len(x.splitlines()) for x in parts)} lines from {len(parts)} sections")


if __name__ == "__main__":
    main()
