"""jaml: Analytic Manifold Learning and an MJX evaluation suite for representation learning."""
