using System;
using System.Collections.Generic;
using System.Globalization;
using System.Linq;
using System.Text;
using System.Threading.Tasks;

namespace Vista.Client.Smoke
{
    /// <summary>
    /// The job scenes a headset lists beside an inspection, read by the protocol core against
    /// a live supervisor: sign in, sync the inspection, download each listed job scene and read
    /// it with <see cref="JobScene"/>. Prints one JSON line per run: each scene's kind, nodes,
    /// figures and animation; exit code 0 only when every scene was read.
    /// Usage: mono scenes.exe BASE_URL USERNAME PASSWORD INSPECTION_ID
    /// </summary>
    public static class JobScenesSmoke
    {
        /// <summary>Entry point: 0 every scene read, 1 a failure, 2 bad arguments.</summary>
        public static int Main(string[] args)
        {
            long inspectionId;
            if (args.Length != 4 || !long.TryParse(args[3], NumberStyles.None, CultureInfo.InvariantCulture, out inspectionId))
            {
                Console.Error.WriteLine("usage: mono scenes.exe BASE_URL USERNAME PASSWORD INSPECTION_ID");
                return 2;
            }
            Console.OutputEncoding = new UTF8Encoding(false);
            try
            {
                Console.WriteLine(Json.Serialize(RunAsync(args[0], args[1], args[2], inspectionId).GetAwaiter().GetResult()));
                return 0;
            }
            catch (Exception error)
            {
                Console.Error.WriteLine("job scenes smoke test failed: " + error);
                return 1;
            }
        }

        static async Task<Dictionary<string, object>> RunAsync(string baseUrl, string username, string password, long inspectionId)
        {
            using (var api = new VistaApi(baseUrl))
            {
                await api.SignInAsync(username, password);
                SyncPage page = await api.GetSyncPageAsync(inspectionId, null);
                var scenes = new List<object>();
                foreach (JobSceneRef listed in page.JobScenes)
                {
                    JobScene scene = JobScene.Parse(await api.GetJobSceneAsync(listed.JobId));
                    Dictionary<string, object> figures = scene.RootExtras.GetObject("figures") ?? new Dictionary<string, object>();
                    scenes.Add(new Dictionary<string, object>
                    {
                        { "job_id", listed.JobId },
                        { "kind", listed.Kind },
                        { "root", scene.NodeNames[0] },
                        { "nodes", scene.NodeNames.Count },
                        { "figures", figures.Keys.OrderBy(k => k, StringComparer.Ordinal).ToList<object>() },
                        { "units", scene.AssetExtras.GetString("units") },
                        { "frame_s", scene.FrameSeconds },
                        { "box_keys", scene.KeysByNode.ContainsKey("tracked-box") ? scene.KeysByNode["tracked-box"] : 0 },
                        { "duration_s", scene.DurationSeconds },
                    });
                }
                return new Dictionary<string, object> { { "scenes", scenes } };
            }
        }
    }
}
