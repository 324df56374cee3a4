// Drives headless Chromium (Debian's, through playwright-core from tests/npm) to Tessera's web
// viewer and screenshots it at given views, once every tile of each view has loaded.
//   node web_viewer_drive.js URL OUT_DIR VIEWS_JSON
// VIEWS_JSON: [{"zoom": screen pixels per image pixel, or "home", "cx": image x at the centre,
// "cy": ...}, ...]. Writes OUT_DIR/view_N.png and prints one JSON line: for each view where image
// pixel (0, 0) and (width, height) landed in the screenshot, and what the page logged.
const { chromium } = require('playwright-core');

const [url, outDir, viewsJson] = process.argv.slice(2);
const views = JSON.parse(viewsJson);

(async () => {
  const browser = await chromium.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    headless: true,
    args: ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run', '--disable-background-networking',
           '--disable-component-update', '--disable-sync'],
  });
  const problems = [];
  try {
    const page = await browser.newPage({ viewport: { width: 960, height: 640 }, deviceScaleFactor: 1 });
    page.on('pageerror', e => problems.push('page error: ' + e));
    page.on('requestfailed', r => problems.push('request failed: ' + r.url()));
    page.on('response', r => { if (r.status() >= 400) problems.push(r.status() + ' ' + r.url()); });
    await page.goto(url);
    await page.waitForFunction(() => window.tessera && (window.tessera.opened || window.tessera.error), null,
                               { timeout: 30000 });
    const opened = await page.evaluate(() => window.tessera.error);
    if (opened) throw new Error('the viewer did not open: ' + opened);
    // Only the image: no bar, navigator or buttons over it.
    await page.evaluate(() => {
      document.getElementById('bar').style.display = 'none';
      for (const c of tessera.viewer.controls) c.element.style.display = 'none';  // buttons, navigator
    });
    const frames = n => page.evaluate(n => new Promise(done => {
      const step = k => k === 0 ? done() : requestAnimationFrame(() => step(k - 1));
      step(n);
    }), n);
    const out = [];
    for (let i = 0; i < views.length; ++i) {
      const v = views[i];
      const placed = await page.evaluate(v => {
        const vp = tessera.viewer.viewport;
        const item = tessera.viewer.world.getItemAt(0);
        const size = item.getContentSize();
        if (v.zoom === 'home') {
          vp.goHome(true);
        } else {
          vp.zoomTo(item.imageToViewportZoom(v.zoom), null, true);
          vp.panTo(item.imageToViewportCoordinates(new OpenSeadragon.Point(v.cx, v.cy)), true);
        }
        const p0 = item.imageToViewerElementCoordinates(new OpenSeadragon.Point(0, 0));
        const p1 = item.imageToViewerElementCoordinates(new OpenSeadragon.Point(size.x, size.y));
        return { x0: p0.x, y0: p0.y, x1: p1.x, y1: p1.y, width: size.x, height: size.y,
                 drawer: tessera.viewer.drawer && tessera.viewer.drawer.getType ? tessera.viewer.drawer.getType() : '' };
      }, v);
      await frames(3);
      await page.waitForFunction(() => tessera.fullyLoaded, null, { timeout: 30000 });
      await frames(3);
      await page.locator('#viewer').screenshot({ path: `${outDir}/view_${i}.png` });
      out.push(placed);
    }
    console.log(JSON.stringify({ views: out, problems }));
  } finally {
    await browser.close();
  }
})().catch(e => { console.error(String(e && e.stack || e)); process.exit(1); });
