"""Speed-against-error benchmarks (``head360 bench ...``): each writes JSON and Markdown."""
