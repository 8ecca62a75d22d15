using System;
using System.IO;
using System.Net.Http;
using System.Threading.Tasks;
using UnityEngine;

namespace Vista.Client.Unity
{
    /// <summary>
    /// The headset's connection to the supervisor: restores the inspection's saved copy and
    /// scene at start (so it works offline at once), then every <see cref="syncIntervalSeconds"/>
    /// pushes the outbox, syncs, and re-downloads the scene when its ETag changed. Without a
    /// network it keeps going on the local copy and reports <see cref="Online"/> false; the
    /// state is saved after every round and every judgment.
    /// <para>Runs before the views (execution order −100) so that <see cref="Sync"/> exists
    /// when they start.</para>
    /// </summary>
    [DefaultExecutionOrder(-100)]
    public sealed class VistaClientBehaviour : MonoBehaviour
    {
        [Tooltip("The supervisor, e.g. https://vista.example:8000")]
        [SerializeField] string serverUrl = "http://localhost:8000";

        [Tooltip("A device token (`vista user create hololens-1 --role device` prints one). Leave empty to sign in with the username and password below.")]
        [SerializeField] string deviceToken = "";

        [SerializeField] string username = "";
        [SerializeField] string password = "";
        [SerializeField] long inspectionId = 1;
        [SerializeField, Min(2f)] float syncIntervalSeconds = 10f;

        [Tooltip("How long one request may take; scene.glb is the largest (about 8 MB at the default 500 000 points).")]
        [SerializeField, Min(5f)] float requestTimeoutSeconds = 120f;
        [SerializeField] SceneLoader sceneLoader;

        VistaApi api;
        Task round;
        bool running;

        /// <summary>Raised after every round (online or not) and every judgment.</summary>
        public event Action StatusChanged;

        /// <summary>The inspection's local copy and outbox (created in Awake).</summary>
        public SyncClient Sync { get; private set; }

        /// <summary>The last round reached the supervisor.</summary>
        public bool Online { get; private set; }

        /// <summary>What went wrong in the last round, for the status line; null when nothing did.</summary>
        public string LastError { get; private set; }

        string StatePath => Path.Combine(Application.persistentDataPath, $"vista-inspection-{inspectionId}.json");

        string ScenePath => Path.Combine(Application.persistentDataPath, $"vista-inspection-{inspectionId}.glb");

        void Awake()
        {
            api = new VistaApi(serverUrl) { Timeout = TimeSpan.FromSeconds(requestTimeoutSeconds) };
            Sync = new SyncClient(api, inspectionId);
        }

        async void Start()
        {
            try
            {
                Sync.LoadState(StatePath);
            }
            catch (FormatException error)
            {
                Debug.LogWarning($"vista: starting afresh, the saved state is unreadable: {error.Message}");
            }
            StatusChanged?.Invoke();
            if (sceneLoader != null && File.Exists(ScenePath))
            {
                await sceneLoader.LoadAsync(File.ReadAllBytes(ScenePath));
            }
            running = true;
            while (running)
            {
                try
                {
                    await SyncNowAsync();
                }
                catch (Exception error)
                {
                    Debug.LogException(error);
                }
                await Task.Delay(TimeSpan.FromSeconds(syncIntervalSeconds));
            }
        }

        void OnDestroy()
        {
            running = false;
            api?.Dispose();
        }

        /// <summary>Judges a defect (shown at once, saved, pushed as soon as the network
        /// allows). Throws <see cref="ArgumentException"/> for a verdict or type the server
        /// would refuse.</summary>
        public void Judge(long defectId, string verdict, string newType, string comment)
        {
            Sync.Judge(defectId, verdict, newType, comment);
            Sync.SaveState(StatePath);
            StatusChanged?.Invoke();
            _ = SyncNowAsync();
        }

        /// <summary>One round now: push, sync, scene. A round already running is joined.</summary>
        public Task SyncNowAsync()
        {
            if (round == null || round.IsCompleted)
            {
                round = RunRoundAsync();
            }
            return round;
        }

        async Task RunRoundAsync()
        {
            try
            {
                await EnsureSignedInAsync();
                if (Sync.Outbox.Count > 0)
                {
                    await Sync.PushAsync();
                }
                await Sync.SyncAsync();
                await RefreshSceneAsync();
                Online = true;
                LastError = null;
            }
            catch (HttpRequestException error)
            {
                Online = false;
                LastError = $"offline ({error.Message}); judgments wait in the outbox";
            }
            catch (TaskCanceledException)
            {
                Online = false;
                LastError = "the supervisor did not answer in time; judgments wait in the outbox";
            }
            catch (VistaApiException problem)
            {
                Online = true;
                LastError = problem.Detail;
                if (problem.Status == 401 && string.IsNullOrEmpty(deviceToken))
                {
                    api.Token = null;
                }
            }
            catch (InvalidOperationException refused)
            {
                LastError = refused.Message;
            }
            catch (FormatException unreadable)
            {
                LastError = $"the supervisor sent something unreadable: {unreadable.Message}";
            }
            finally
            {
                Sync.SaveState(StatePath);
                StatusChanged?.Invoke();
            }
        }

        /// <summary>Signs in when there is no token yet, and learns who that is. The outbox
        /// is never pushed under another user than the one who judged.</summary>
        async Task EnsureSignedInAsync()
        {
            if (!string.IsNullOrEmpty(api.Token) && Sync.User != null)
            {
                return;
            }
            if (!string.IsNullOrEmpty(deviceToken))
            {
                api.Token = deviceToken;
            }
            else
            {
                await api.SignInAsync(username, password);
            }
            UserInfo me = await api.GetMeAsync();
            if (Sync.User != null && Sync.User.Id != me.Id && Sync.Outbox.Count > 0)
            {
                api.Token = null;
                throw new InvalidOperationException(
                    $"The outbox holds judgments of {Sync.User.Username}; sign in as {Sync.User.Username} to send them.");
            }
            Sync.User = me;
        }

        async Task RefreshSceneAsync()
        {
            bool haveCopy = File.Exists(ScenePath);
            if (sceneLoader == null || (haveCopy && !Sync.SceneChanged))
            {
                return;
            }
            SceneDownload scene = await Sync.DownloadSceneAsync(haveCopy);
            if (!scene.NotModified && await sceneLoader.LoadAsync(scene.Bytes))
            {
                File.WriteAllBytes(ScenePath, scene.Bytes);
            }
        }
    }
}
