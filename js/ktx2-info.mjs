// Parses KTX2 files with ktx-parse (an independent reader) and prints one JSON object per file:
// header fields, the Data Format Descriptor, the levels' byte lengths and the key/value data.
// Usage: node ktx2-info.mjs FILE.ktx2 [...]
import { readFileSync } from 'node:fs';
import { read } from 'ktx-parse';

const decoder = new TextDecoder();
const out = process.argv.slice(2).map((file) => {
	const c = read(new Uint8Array(readFileSync(file)));
	const keyValue = {};
	for (const [k, v] of Object.entries(c.keyValue)) {
		keyValue[k] = typeof v === 'string' ? v : decoder.decode(v).replace(/\0+$/, '');
	}
	const d = c.dataFormatDescriptor[0];
	return {
		file, vkFormat: c.vkFormat, typeSize: c.typeSize, pixelWidth: c.pixelWidth, pixelHeight: c.pixelHeight,
		pixelDepth: c.pixelDepth, layerCount: c.layerCount, faceCount: c.faceCount, levelCount: c.levels.length,
		supercompressionScheme: c.supercompressionScheme,
		levelBytes: c.levels.map((l) => l.levelData.byteLength),
		dfd: { colorModel: d.colorModel, colorPrimaries: d.colorPrimaries, transferFunction: d.transferFunction,
			flags: d.flags, bytesPlane: Array.from(d.bytesPlane),
			samples: d.samples.map((s) => ({ bitOffset: s.bitOffset, bitLength: s.bitLength, channelType: s.channelType,
				sampleLower: s.sampleLower, sampleUpper: s.sampleUpper })) },
		keyValue,
	};
});
process.stdout.write(JSON.stringify(out));
