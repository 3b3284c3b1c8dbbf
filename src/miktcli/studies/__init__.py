"""Studies: a grid of transfers (pairs × methods × seeds), planned and resumed from state.json, trained by an
executor (serial in this process, or on Ray), and reported from one summary by separate renderers."""
