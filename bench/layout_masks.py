"""Re-create DATA_DIR/masks/<source>/ and DATA_DIR/photos/<source>/ for bench/mask_sources.py and
bench/validate_real.py from public GitHub repositories.

    python bench/layout_masks.py DATA_DIR

Needs the repositories as bare git directories (the session's `fetch` tool puts them under
/work/.mirror/<owner>+<name>/repo; anything else: `git clone --bare`, then set MIRROR or edit
REPOS). Every file is read at its pinned commit with `git show COMMIT:path`; photos are copied
byte for byte (one source is re-encoded, said so below) and masks are converted to the layout's
encoding: ``NAME_mask.png``, 8-bit grey, 255 = plant (crop and weeds alike), 0 = soil and
everything else, the size of the photo as viewed (EXIF orientation applied). The sha1 (git blob
ids) of everything written, with the blob it came from, go to DATA_DIR/masks/MANIFEST and
DATA_DIR/photos/MANIFEST; DATA_DIR/masks/SOURCES.md describes every source. Running it again
rewrites nothing that is already right (files are compared before they are written).

Subsets are chosen in sorted order of the file names with ``spread(names, k)``: the k names at
positions round(i * (n - 1) / (k - 1)), i = 0 .. k - 1 (the first and the last always in).

Sources with hand-annotated masks (DATA_DIR/masks/):

cwfid                  cwfid/dataset @ 36290d0: images/NNN_image.png -> NNN.png, masks/NNN_mask.png
                       (1-bit, 1 = soil, 0 = plant: inverted), spread(60, 20).
segveg_literal_wheat   mserouar/SegVeg @ 98a7fc6 (the path is deleted at HEAD):
                       docs/DATA/Literal_wheat_dataset/images/LiteralDataset_N.png, the masks in
                       images/result/ (8-bit, 255 = green or senescent vegetation; copied),
                       spread(67, 24).
peanut                 ptdkhoa/Peanut-dataset @ ec8e68d: images/NNNN.jpg, labels/NNNN.png (RGB:
                       green crop, red weed, black background; plant = not black), spread(400, 20).
carrotweed             lameski/rgbweeddetection @ 2220f89: Images/IMG_N.JPG, Vegetation_Masks/
                       IMG_N.png (RGBA, anti-aliased white plants on black; plant = grey > 127),
                       all 39. The JPEGs carry EXIF orientation 3 (180 degrees) on most frames and
                       the masks are drawn on the photo as viewed, so the photo is written as
                       IMG_N.png with the orientation applied (readers ignoring EXIF agree too).
ews_wheat              supervisely-ecosystem/EWS-Dataset-training-data @ aa94606: project/
                       {train,validation}/img/NAME.png and ann/NAME.png.json (Supervisely: class
                       `Wheat` bitmaps, base64 of zlib of a PNG, placed at their `origin`): all 24
                       of validation and spread(142, 24) of train.

maize_sugarbeet        Schine73/Plant-and-Weed-detection-using-UNet-CNN @ 8513885: training_images/
                       NAME.jpg and NAME.png (8-bit classes: 0 background, 1 weed, 2 sugar beet,
                       3 maize; plant = 1-3), spread(154, 30) of the pairs whose photo is under
                       4 MiB (SCHINE_MAX_BYTES: the snapshot holds no bigger file).

weedsgalore            koesan/weedseg @ a009f40: WeedsGalore/yolo_dataset/images/test/DATE_ID.png and
                       labels/test/DATE_ID.txt (YOLO segmentation polygons, classes 0 crop and 1
                       weed, traced by that repository from WeedsGalore's masks; every polygon
                       filled as plant), all 26.
stover_residue         soilwater/stover @ 8c0e980: dataset_v2/image_data/image_NNNN.jpg and
                       label_data/label_NNNN.png (8-bit classes: 0 soil, 1 green canopy, 2 residue;
                       plant = 1), spread(468, 30) of the frames whose own cover table
                       (images_registry_outputs.csv) gives more than 1 % plant and 10 % residue.

Photos without masks (DATA_DIR/photos/; the reference is an index mask made by the reader):

maize_rows_straw       WoodratTradeCo/crop-rows-detection @ d75cf5e: mydata/images/{test,train}/
                       N.jpg -> {test,train}_N.jpg, all 22 (its labels are row boxes, not masks).
uavbroccoli            UTokyo-FieldPhenomics-Lab/UAVbroccoli @ f30abe2 (the folder is deleted in
                       the next commit): data/broccoli_data/images/train/grid_xNN_yNN.jpg, the six
                       tiles in BROCCOLI_TILES (the first layout's choice, by name; no rule of
                       position reproduces it).
"""

from __future__ import annotations

import base64
import csv
import io
import json
import sys
import zlib
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench import _mirror as mirror  # noqa: E402

REPOS = {
    "cwfid": ("cwfid/dataset", "36290d0912a032f0bd1a5678ed55457ddafde217"),
    "segveg": ("mserouar/SegVeg", "98a7fc627e2cf854e8e1b17e89215f91e3623833"),
    "peanut": ("ptdkhoa/Peanut-dataset", "ec8e68d19b15487c56a6cff6f309f822861b05f9"),
    "carrotweed": ("lameski/rgbweeddetection", "2220f89bcae92650090db8502c090740f72f241f"),
    "ews": ("supervisely-ecosystem/EWS-Dataset-training-data", "aa9460619728e7e7a7cc84d4b892fa20ffdf5b1b"),
    "schine": (
        "Schine73/Plant-and-Weed-detection-using-UNet-CNN",
        "8513885c73e4974153cddfddf0f4a6238ef3947b",
    ),
    "maize_rows": ("WoodratTradeCo/crop-rows-detection", "d75cf5e0412c5cdfaef1e9e99f53507e98d7fd3b"),
    "uavbroccoli": ("UTokyo-FieldPhenomics-Lab/UAVbroccoli", "f30abe2c736eb479d346dff52246cea363cb56c1"),
    "weedseg": ("koesan/weedseg", "a009f40f682d771d59ff3088e914ae6fa37792fe"),
    "stover": ("soilwater/stover", "8c0e980e8cccc94dca913e3bfc92a6ea9d77d0c7"),
}
BROCCOLI_TILES = (
    "grid_x02_y06",
    "grid_x06_y15",
    "grid_x09_y11",
    "grid_x10_y20",
    "grid_x13_y12",
    "grid_x17_y13",
)


def git(key, *args):
    return mirror.git(REPOS[key][0], *args)


def blob(key, path):
    """The bytes of `path` at the pinned commit."""
    return mirror.blob(*REPOS[key], path)


def listing(key, folder):
    """Sorted file names (not paths) directly in `folder` at the pinned commit."""
    out = git(key, "ls-tree", "--name-only", REPOS[key][1], folder.rstrip("/") + "/").decode()
    return sorted(Path(p).name for p in out.split("\n") if p)


def spread(names, k):
    """k of the sorted `names`, evenly spread: positions round(i (n - 1) / (k - 1)), halves up."""
    names = sorted(names)
    n = len(names)
    if k >= n:
        return names
    return [names[(2 * i * (n - 1) + (k - 1)) // (2 * (k - 1))] for i in range(k)]


def write(target, data):
    """Write `data` unless `target` already holds it; its git blob id."""
    target.parent.mkdir(parents=True, exist_ok=True)
    if not (target.is_file() and target.read_bytes() == data):
        target.write_bytes(data)
    return mirror.blob_id(data)


def png_bytes(image):
    buf = io.BytesIO()
    image.save(buf, format="PNG")
    return buf.getvalue()


def mask_png(plant):
    """A boolean array as the layout's mask: 8-bit grey PNG, 255 = plant, 0 = soil."""
    return png_bytes(Image.fromarray(np.where(plant, 255, 0).astype(np.uint8)))


def open_image(data):
    image = Image.open(io.BytesIO(data))
    image.load()
    return image


class Layout:
    """Writes one source's files and remembers them for the MANIFESTs."""

    def __init__(self, data_dir):
        self.data_dir = data_dir
        self.manifest = {"masks": {}, "photos": {}}

    def put(self, kind, source, name, data, key, path, how="copy"):
        target = self.data_dir / kind / source / name
        self.manifest[kind][f"{source}/{name}"] = (write(target, data), key, path, how)
        return target

    def copy(self, kind, source, name, key, path):
        return self.put(kind, source, name, blob(key, path), key, path)


def cwfid(out):
    names = spread([n for n in listing("cwfid", "images") if n.endswith("_image.png")], 20)
    for name in names:
        stem = name.removesuffix("_image.png")
        out.copy("masks", "cwfid", f"{stem}.png", "cwfid", f"images/{name}")
        path = f"masks/{stem}_mask.png"
        mask = np.asarray(open_image(blob("cwfid", path)).convert("L"))
        values = set(np.unique(mask).tolist())
        if not values <= {0, 1, 255}:
            raise SystemExit(f"cwfid {path}: values {sorted(values)}, expected two")
        # 1-bit masks: the soil is set, the plants (crop and weeds) are 0.
        out.put("masks", "cwfid", f"{stem}_mask.png", mask_png(mask == 0), "cwfid", path, "inverted")


def segveg_literal_wheat(out):
    folder = "docs/DATA/Literal_wheat_dataset/images"
    for name in spread([n for n in listing("segveg", folder) if n.endswith(".png")], 24):
        out.copy("masks", "segveg_literal_wheat", name, "segveg", f"{folder}/{name}")
        path = f"{folder}/result/{name}"
        data = blob("segveg", path)
        mask = open_image(data)
        values = set(np.unique(np.asarray(mask)).tolist())
        if mask.mode == "L" and values <= {0, 255}:
            out.put("masks", "segveg_literal_wheat", name.replace(".png", "_mask.png"), data, "segveg", path)
        else:
            plant = np.asarray(mask.convert("L")) > 127
            out.put(
                "masks",
                "segveg_literal_wheat",
                name.replace(".png", "_mask.png"),
                mask_png(plant),
                "segveg",
                path,
                "to 0/255",
            )


def peanut(out):
    for name in spread([n for n in listing("peanut", "images") if n.endswith(".jpg")], 20):
        stem = name.removesuffix(".jpg")
        out.copy("masks", "peanut", name, "peanut", f"images/{name}")
        path = f"labels/{stem}.png"
        rgb = np.asarray(open_image(blob("peanut", path)).convert("RGB"))
        colours = {tuple(c) for c in np.unique(rgb.reshape(-1, 3), axis=0).tolist()}
        if not colours <= {(0, 0, 0), (0, 255, 0), (255, 0, 0)}:
            raise SystemExit(f"peanut {path}: colours {sorted(colours)[:8]}, expected black, green, red")
        out.put(
            "masks", "peanut", f"{stem}_mask.png", mask_png(rgb.any(axis=2)), "peanut", path, "crop + weed"
        )


def carrotweed(out):
    for name in listing("carrotweed", "Images"):
        stem = Path(name).stem
        photo = ImageOps.exif_transpose(open_image(blob("carrotweed", f"Images/{name}"))).convert("RGB")
        out.put(
            "masks",
            "carrotweed",
            f"{stem}.png",
            png_bytes(photo),
            "carrotweed",
            f"Images/{name}",
            "EXIF applied, PNG",
        )
        path = f"Vegetation_Masks/{stem}.png"
        mask = open_image(blob("carrotweed", path)).convert("RGB").convert("L")
        if mask.size != photo.size:
            raise SystemExit(f"carrotweed {path}: {mask.size}, photo {photo.size}")
        out.put(
            "masks",
            "carrotweed",
            f"{stem}_mask.png",
            mask_png(np.asarray(mask) > 127),
            "carrotweed",
            path,
            "grey > 127",
        )


def supervisely_mask(ann, classes):
    """The union of `ann`'s bitmap objects of `classes`, full size (bool)."""
    plant = np.zeros((ann["size"]["height"], ann["size"]["width"]), bool)
    for obj in ann["objects"]:
        if obj["classTitle"] not in classes:
            continue
        if obj["geometryType"] != "bitmap":
            raise SystemExit(f"unexpected geometry {obj['geometryType']}")
        bitmap = open_image(zlib.decompress(base64.b64decode(obj["bitmap"]["data"])))
        a = np.asarray(bitmap)
        a = a[..., 3] if bitmap.mode in ("RGBA", "LA") else (a if a.ndim == 2 else a.any(axis=2))
        x, y = obj["bitmap"]["origin"]
        h, w = a.shape
        plant[y : y + h, x : x + w] |= a > 0
    return plant


def ews_wheat(out):
    chosen = [("validation", n) for n in listing("ews", "project/validation/img")]
    chosen += [("train", n) for n in spread(listing("ews", "project/train/img"), 24)]
    for split, name in chosen:
        out.copy("masks", "ews_wheat", name, "ews", f"project/{split}/img/{name}")
        path = f"project/{split}/ann/{name}.json"
        plant = supervisely_mask(json.loads(blob("ews", path)), {"Wheat"})
        out.put(
            "masks", "ews_wheat", f"{Path(name).stem}_mask.png", mask_png(plant), "ews", path, "Wheat bitmaps"
        )


# Photos of Schine73/Plant-and-Weed-detection-using-UNet-CNN above this size are left out: the
# snapshot the layout was made from holds no file of 4 MiB or more (328 of its 482 phone photos).
SCHINE_MAX_BYTES = 4 * 2**20
SCHINE_PLANT = (1, 2, 3)  # weed, sugar beet, maize; 0 is background


def maize_sugarbeet(out):
    folder = "training_images"
    sizes = {}
    for line in git("schine", "ls-tree", "-l", REPOS["schine"][1], folder + "/").decode().splitlines():
        meta, path = line.split("\t")
        size = meta.split()[3]
        sizes[Path(path).name] = int(size) if size.isdigit() else None  # None: not in this copy
    pairs = [
        name
        for name in sizes
        if name.endswith(".jpg")
        and sizes[name] is not None
        and sizes[name] < SCHINE_MAX_BYTES
        and f"{Path(name).stem}.png" in sizes
    ]
    for name in spread(pairs, 30):
        stem = Path(name).stem
        photo_path, path = f"{folder}/{name}", f"{folder}/{stem}.png"
        photo = open_image(blob("schine", photo_path))
        labels = np.asarray(open_image(blob("schine", path)))
        if labels.shape != (photo.height, photo.width) or photo.getexif().get(0x0112, 1) != 1:
            raise SystemExit(f"maize_sugarbeet {path}: {labels.shape}, photo {photo.size} (EXIF rotated?)")
        if not set(np.unique(labels).tolist()) <= {0, *SCHINE_PLANT}:
            raise SystemExit(f"maize_sugarbeet {path}: classes {np.unique(labels)}, expected 0-3")
        out.copy("masks", "maize_sugarbeet", name, "schine", photo_path)
        out.put(
            "masks", "maize_sugarbeet", f"{stem}_mask.png", mask_png(np.isin(labels, SCHINE_PLANT)),
            "schine", path, "classes 1-3",
        )  # fmt: skip


def yolo_polygons_mask(text, size):
    """The plant mask of a YOLO segmentation label file: every polygon (any class) filled.

    Each line is ``class x1 y1 x2 y2 ...`` with coordinates in [0, 1] of the image's (width,
    height); PIL fills each polygon with its outline.
    """
    from PIL import ImageDraw

    mask = Image.new("L", size, 0)
    draw = ImageDraw.Draw(mask)
    for line in text.splitlines():
        values = line.split()
        if len(values) < 7:  # a class and at least three points
            continue
        xy = np.asarray(values[1:], dtype=np.float64).reshape(-1, 2) * np.asarray(size, dtype=np.float64)
        draw.polygon([tuple(point) for point in xy], fill=255)
    return np.asarray(mask) > 0


def weedsgalore(out):
    folder = "WeedsGalore/yolo_dataset"
    for name in listing("weedseg", f"{folder}/images/test"):
        if not name.endswith(".png"):
            continue
        stem = Path(name).stem
        photo_path, path = f"{folder}/images/test/{name}", f"{folder}/labels/test/{stem}.txt"
        photo = open_image(blob("weedseg", photo_path))
        plant = yolo_polygons_mask(blob("weedseg", path).decode(), photo.size)
        out.copy("masks", "weedsgalore", name, "weedseg", photo_path)
        out.put(
            "masks", "weedsgalore", f"{stem}_mask.png", mask_png(plant), "weedseg", path,
            "YOLO polygons filled",
        )  # fmt: skip


# Stover's frames with plants among residue: more than these percentages in its own cover table.
STOVER_MIN_PLANT, STOVER_MIN_RESIDUE = 1.0, 10.0


def stover_frames(table):
    """{photo name: row} of Stover's cover table (CSV text) with plants among residue: more than
    STOVER_MIN_PLANT % green canopy and STOVER_MIN_RESIDUE % residue in its label maps."""
    return {
        row["name"]: row
        for row in csv.DictReader(io.StringIO(table))
        if float(row["true_plant"]) > STOVER_MIN_PLANT and float(row["true_residue"]) > STOVER_MIN_RESIDUE
    }


def stover_residue(out):
    folder = "dataset_v2"
    rows = stover_frames(blob("stover", f"{folder}/images_registry_outputs.csv").decode())
    for name in spread(rows, 30):
        row = rows[name]
        photo_path, path = f"{folder}/image_data/{name}", f"{folder}/label_data/{row['label']}"
        labels = np.asarray(open_image(blob("stover", path)))
        photo = open_image(blob("stover", photo_path))
        if labels.shape != (photo.height, photo.width) or not set(np.unique(labels).tolist()) <= {0, 1, 2}:
            raise SystemExit(f"stover_residue {path}: {labels.shape} {np.unique(labels)}, photo {photo.size}")
        # The label map is the one the table describes: its plant share to the table's 0.01 %.
        if abs(100 * (labels == 1).mean() - float(row["true_plant"])) > 0.01:
            raise SystemExit(
                f"stover_residue {path}: plant {100 * (labels == 1).mean():.2f} %, table {row['true_plant']}"
            )
        out.copy("masks", "stover_residue", name, "stover", photo_path)
        out.put(
            "masks", "stover_residue", f"{Path(name).stem}_mask.png", mask_png(labels == 1), "stover", path,
            "class 1",
        )  # fmt: skip


def maize_rows_straw(out):
    for split in ("test", "train"):
        for name in listing("maize_rows", f"mydata/images/{split}"):
            out.copy(
                "photos", "maize_rows_straw", f"{split}_{name}", "maize_rows", f"mydata/images/{split}/{name}"
            )


def uavbroccoli(out):
    folder = "data/broccoli_data/images/train"
    names = listing("uavbroccoli", folder)
    for tile in BROCCOLI_TILES:
        if f"{tile}.jpg" not in names:
            raise SystemExit(f"uavbroccoli: no {tile}.jpg in {folder}")
        out.copy("photos", "uavbroccoli", f"{tile}.jpg", "uavbroccoli", f"{folder}/{tile}.jpg")


# What each source is, for SOURCES.md: the folder, the function that lays it out, the REPOS key.
SOURCES = [
    {
        "folder": "cwfid",
        "kind": "masks",
        "make": cwfid,
        "repo": "cwfid",
        "files": "images/NNN_image.png -> NNN.png; masks/NNN_mask.png; 20 of 60 by spread()",
        "crop": "carrot seedlings with weeds (CWFID, Haug and Ostermann 2015)",
        "soil": "dark, moist, cloddy soil",
        "light": "nadir from a field robot (not a UAV); the colours look like a NIR-sensitive camera",
        "stage": "seedlings; crop and weeds overlap",
        "licence": '"non-commercial research only", cite Haug and Ostermann, CVPPP 2014 / ECCV 2014 '
        "workshops (README; no licence file)",
        "reference": "the dataset's vegetation masks (hand-made): crop and weeds are plant. Its masks "
        "are 1-bit with 1 = soil and 0 = plant, inverted here",
    },
    {
        "folder": "segveg_literal_wheat",
        "kind": "masks",
        "make": segveg_literal_wheat,
        "repo": "segveg",
        "files": "docs/DATA/Literal_wheat_dataset/images/LiteralDataset_N.png, masks images/result/"
        "LiteralDataset_N.png; 24 of 67 by spread() (the folder is deleted at HEAD)",
        "crop": "wheat plots, LITERAL handheld nadir camera (France)",
        "soil": "little visible; brown, dry",
        "light": "sun, hard shadows",
        "stage": "green, yellowing and ripe canopy (senescent leaves and ears)",
        "licence": "none stated",
        "reference": "the repository's binary masks (255 = green or senescent vegetation, copied as "
        "they are); probably the SegVeg model's output, not verified as hand-drawn",
    },
    {
        "folder": "peanut",
        "kind": "masks",
        "make": peanut,
        "repo": "peanut",
        "files": "images/NNNN.jpg, labels/NNNN.png; 20 of 400 by spread() (every 21st)",
        "crop": "peanut with weeds (goose grass, nut grass), near Danang, Vietnam",
        "soil": "brown, dry to moist, some residue",
        "light": "sun and shadows; handheld photos, nadir to oblique",
        "stage": "seedlings to young plants",
        "licence": "CC BY-SA 4.0 (README); cite Tran and Phan, IEEE Access 11 (2023) 82640-82651",
        "reference": "hand-labelled colour maps (green crop, red weed, black background): crop and "
        "weeds are plant",
    },
    {
        "folder": "carrotweed",
        "kind": "masks",
        "make": carrotweed,
        "repo": "carrotweed",
        "files": "Images/IMG_N.JPG -> IMG_N.png (EXIF orientation applied: the masks are drawn on the "
        "photo as viewed), Vegetation_Masks/IMG_N.png; all 39",
        "crop": "carrot seedlings with weeds (Carrot-Weed, Macedonia)",
        "soil": "brown soil with clods",
        "light": "low sun with hard shadows, and overcast; handheld, nadir-ish",
        "stage": "seedlings",
        "licence": '"free for non-commercial applications", cite Lameski et al., ICT Innovations '
        "2017 (README)",
        "reference": "hand-drawn vegetation masks (anti-aliased RGBA, white plants: grey > 127): crop "
        "and weeds are plant",
    },
    {
        "folder": "ews_wheat",
        "kind": "masks",
        "make": ews_wheat,
        "repo": "ews",
        "files": "project/{train,validation}/img/NAME.png, ann/NAME.png.json; all 24 of validation "
        "and 24 of 142 of train by spread()",
        "crop": "winter wheat plots (Eschikon Wheat Segmentation, ETH Zurich, 2017-2020)",
        "soil": "pale dry to dark moist",
        "light": "sun with hard shadows, and diffuse; nadir, 350 px patches of 20 Mpx photos",
        "stage": "emergence to stem elongation",
        "licence": "CC BY-SA 4.0 (README); cite Zenkl et al., Front. Plant Sci. 12:774068 (2022)",
        "reference": "hand annotations, class `Wheat` (Supervisely bitmaps: base64 of zlib of a PNG "
        "placed at its origin)",
    },
    {
        "folder": "maize_sugarbeet",
        "kind": "masks",
        "make": maize_sugarbeet,
        "repo": "schine",
        "files": "training_images/NAME.jpg, training_images/NAME.png; 30 by spread() of the 154 "
        "pairs whose photo is under 4 MiB",
        "crop": "young maize rows and sugar beet, with weeds (Wiener Neustadt, Austria, 2022)",
        "soil": "dark moist loam with straw bits; pale dry crusted soil; light brown clods",
        "light": "overcast, and low sun with hard shadows; handheld phone, nadir",
        "stage": "seedlings (maize 2-4 leaves, beet 2-6 leaves)",
        "licence": '"The images were taken and hand segmented by me and my class colleagues. Feel '
        'free to use them for your own purposes." (README; no licence file)',
        "reference": "hand-segmented class maps (0 background, 1 weed, 2 sugar beet, 3 maize): crop "
        "and weeds are plant",
    },
    {
        "folder": "weedsgalore",
        "kind": "masks",
        "make": weedsgalore,
        "repo": "weedseg",
        "files": "WeedsGalore/yolo_dataset/images/test/DATE_ID.png, labels/test/DATE_ID.txt; all 26",
        "crop": "maize with four weed species, UAV nadir (WeedsGalore, Celikkan et al., WACV 2025; "
        "Brandenburg, Germany, 2023)",
        "soil": "pale, dry, sandy soil",
        "light": "sun with hard shadows; UAV nadir, RGB bands of a multispectral camera",
        "stage": "four dates from emergence (most frames under 2 % cover) to rows closing (55 %)",
        "licence": 'WeedsGalore: "distributed under the Creative Commons Attribution (CC BY) Licence" '
        "(GFZ/weedsgalore README); cite Celikkan et al., WACV 2025. koesan/weedseg, which holds "
        "this copy, has no licence file",
        "reference": "the dataset's dense crop and weed annotations, as koesan/weedseg traced them to "
        "YOLO polygons (filled here; small plants and holes may be lost); not verified as hand-drawn "
        "from the paper's text",
    },
    {
        "folder": "stover_residue",
        "kind": "masks",
        "make": stover_residue,
        "repo": "stover",
        "files": "dataset_v2/image_data/image_NNNN.jpg, label_data/label_NNNN.png; 30 by spread() of "
        "the 468 frames with more than 1 % plant and 10 % residue in images_registry_outputs.csv",
        "crop": "corn, sorghum, soybean, sunflower and wheat in no-till residue (Stover, Kansas State "
        "University)",
        "soil": "straw and stalk residue over brown soil, from a few stalks to full cover",
        "light": "sun with hard shadows, and diffuse; handheld nadir, 0.6-0.9 m, 512 px crops",
        "stage": "seedlings to closed rows",
        "licence": "the repository is MIT; its dataset release states CC BY 4.0; cite Patrignani, "
        "Bisheh and Nahitiya, Agronomy Journal (in press)",
        "reference": "the dataset's label maps (0 soil, 1 green canopy, 2 residue): green canopy is "
        "plant. They look threshold-made and edited by hand (pixel-fine edges, brush-sized blocks), "
        "not drawn from scratch; senescent plant material is labelled residue",
    },
    {
        "folder": "maize_rows_straw",
        "kind": "photos",
        "make": maize_rows_straw,
        "repo": "maize_rows",
        "files": "mydata/images/{test,train}/N.jpg -> {test,train}_N.jpg; all 22",
        "crop": "young maize rows (about V3-V6)",
        "soil": "straw-covered no-till soil",
        "light": "overcast; oblique tractor camera",
        "stage": "young plants, rows open",
        "licence": "GPL-3.0 (the repository's; no separate data licence)",
        "reference": "none (its labels are row boxes): the reader's independent ExG/Otsu mask",
    },
    {
        "folder": "uavbroccoli",
        "kind": "photos",
        "make": uavbroccoli,
        "repo": "uavbroccoli",
        "files": "data/broccoli_data/images/train/grid_xNN_yNN.jpg, the six tiles of BROCCOLI_TILES "
        "(the folder is deleted in the next commit)",
        "crop": "broccoli, UAV orthomosaic tiles (Tokyo)",
        "soil": "very dark soil",
        "light": "UAV nadir",
        "stage": "heading; pale, bluish plants",
        "licence": "MIT for the code; the data's is unclear",
        "reference": "none: the reader's independent ExG/Otsu mask",
    },
]


def sources_md(stats):
    lines = [
        "# Plant/soil mask sources",
        "",
        "Written by `bench/layout_masks.py` (in the Cliff Terrain repository). Every file comes from "
        "a public GitHub repository at the commit given; `MANIFEST` beside this file and "
        "`../photos/MANIFEST` list each file's git blob id and its origin. `masks/<source>/NAME_mask.png`: "
        "8-bit grey, 255 = plant (crop and weeds alike), 0 = soil, residue and the rest, the size of "
        "the photo as viewed. `photos/<source>/`: photos without a hand mask. None of these licences "
        "lets the data into the repository without conditions: keep it outside.",
        "",
    ]
    for src in SOURCES:
        repo, commit = REPOS[src["repo"]]
        n, cover = stats.get(src["folder"], (0, None))
        lines += [
            f"## `{src['kind']}/{src['folder']}`",
            "",
            f"- images: {n}"
            + (f", median plant cover of the masks {cover:.1%}" if cover is not None else ""),
            f"- crop: {src['crop']}",
            f"- soil: {src['soil']}",
            f"- light, view: {src['light']}",
            f"- stage: {src['stage']}",
            f"- reference: {src['reference']}",
            f"- licence: {src['licence']}",
            f"- origin: https://github.com/{repo}, commit `{commit}`",
            f"- files: {src['files']}",
            "",
        ]
    return "\n".join(lines)


def check(data_dir, kind, folder):
    """(images, median plant cover, median correlation of ExG with the mask) of one folder;
    raises on a photo without a mask of its size and of values {0, 255}."""
    covers, corrs = [], []
    photos = [
        p
        for p in sorted((data_dir / kind / folder).iterdir())
        if p.suffix.lower() in (".png", ".jpg", ".jpeg", ".tif", ".tiff") and not p.stem.endswith("_mask")
    ]
    for photo in photos if kind == "masks" else []:
        mask_path = photo.with_name(photo.stem + "_mask.png")
        if not mask_path.is_file():
            raise SystemExit(f"{photo}: no {mask_path.name}")
        with Image.open(photo) as im:
            image = ImageOps.exif_transpose(im)
            image.draft("RGB", (image.width // 4, image.height // 4))
            size = image.size
            rgb = image.convert("RGB")
        with Image.open(mask_path) as m:
            if m.mode != "L" or m.size != size:
                raise SystemExit(f"{mask_path}: {m.mode} {m.size}, photo {size}")
            mask = np.asarray(m)
        if not set(np.unique(mask).tolist()) <= {0, 255}:
            raise SystemExit(f"{mask_path}: values other than 0 and 255")
        plant = mask > 127
        covers.append(float(plant.mean()))
        step = max(1, max(size) // 500)
        small = np.asarray(rgb.resize((size[0] // step, size[1] // step)), float)
        exg = 2 * small[..., 1] - small[..., 0] - small[..., 2]
        ref = np.asarray(Image.fromarray(mask).resize(small.shape[1::-1], Image.NEAREST)) > 127
        if 0 < ref.mean() < 1:
            corrs.append(float(np.corrcoef(exg.ravel(), ref.ravel())[0, 1]))
    return len(photos), _median(covers), _median(corrs)


def _median(values):
    return float(np.median(values)) if values else None


def write_manifest(path, entries):
    lines = []
    for target, (sha, key, src, how) in sorted(entries.items()):
        repo, commit = REPOS[key]
        lines.append(
            f"{sha}  {target}  <- {repo}@{commit[:7]}:{src}" + ("" if how == "copy" else f" ({how})")
        )
    write(path, ("\n".join(lines) + "\n").encode())


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    data = Path(argv[0]) if argv else Path(__file__).resolve().parent
    out = Layout(data)
    for src in SOURCES:
        print(src["folder"], flush=True)
        src["make"](out)
    stats = {}
    print(f"{'source':24s} {'kind':7s} {'images':>6s} {'median plant':>12s} {'ExG~mask r':>10s}")
    for src in SOURCES:
        kind = src["kind"]
        n, cover, corr = check(data, kind, src["folder"])
        stats[src["folder"]] = (n, cover)
        expected = sum(
            1 for t in out.manifest[kind] if t.startswith(src["folder"] + "/") and "_mask." not in t
        )
        extra = "" if n == expected else f"  ({n - expected} files not from this layout)"
        print(
            f"{src['folder']:24s} {kind:7s} {n:6d} "
            + (f"{cover:12.1%} {corr:10.2f}" if cover is not None else f"{'-':>12s} {'-':>10s}")
            + extra
        )
    for kind, entries in out.manifest.items():
        write_manifest(data / kind / "MANIFEST", entries)
    write(data / "masks" / "SOURCES.md", sources_md(stats).encode())
    print(f"{sum(len(e) for e in out.manifest.values())} files under {data / 'masks'} and {data / 'photos'}")


if __name__ == "__main__":
    main()
