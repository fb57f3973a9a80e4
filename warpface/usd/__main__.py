"""``python -m warpface.usd``: regenerate the schema plugin's generatedSchema.usda and plugInfo.json from
schema.usda."""

from .schema import regenerate_schema

if __name__ == "__main__":
    for path in regenerate_schema():
        print(f"wrote {path}")
