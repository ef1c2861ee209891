"""The one leaf that writes files and draws: study reports, fit reports, benchmark results, URDFs."""
